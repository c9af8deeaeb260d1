//! The presets of the learner's settings and each task's default pipeline.

use std::path::PathBuf;

use super::{CloneStage, RewardArg, TaskArg, TrainSettings};
use crate::learn::RunConfig;

/// Named starting points for the learner's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PresetArg {
    /// The paper's plain DDPG: no demonstrations, no TD3 pieces, one-step returns, white noise.
    Paper,
    /// The learner from demonstrations (the default of `trainer train --task reach` without a
    /// settings file; until session 16 also of the other tasks: the Grasp ablation's `no-norm`
    /// row, 47/50 and 46/50): 200 recorded Markov-demonstrator episodes,
    /// 20,000 pre-training updates (actor lr 3e-4), a quarter of each batch from them with the
    /// cloning term on every row, TD3+BC's Q normalisation 2.5, actor lr 3e-5, raw observations,
    /// gamma 0.98 for the 150-step tasks.
    Demos,
    /// The pipeline of issue #26: a clone stage (`trainer imitate`'s recipe for the task, with the
    /// task features) and reinforcement learning from the clone that cannot forget it: 40,000
    /// transitions (the `budget` the preset sets when the run gives none), a critic warm-up of
    /// 10,000 updates on the clone's own transitions before the actor moves, R = 2, actor lr
    /// 3e-5, 200 recorded Markov demonstrations a quarter of each batch with the cloning term at
    /// weight 5 and TD3+BC's Q normalisation 2.5, gamma 0.98, the clone's 256-256 actor
    /// (`experiments/finetune/*-features-clone-bc5.toml`; docs/experiments.md, session 14:
    /// StackInHand 989 -> 995 of 1000, Stack 974 -> 981, Grasp 989 -> 978), guarded against the
    /// clone on [`FINETUNE_GUARD_EPISODES`] selection starts. On Grasp and Stack the clone stage
    /// is the shipped file's recipe ([`CloneStage::for_task`]; a run with its own `[clone]` keeps
    /// that). The default of `trainer train --task grasp|stack-in-hand|stack`
    /// without a settings file ([`TaskArg::default_pipeline`]).
    Finetune,
}

/// Transitions of the [`PresetArg::Finetune`] stage after the clone.
pub const FINETUNE_TRANSITIONS: u64 = 40_000;

/// Selection starts of the [`PresetArg::Finetune`] guard ([`TrainSettings::guard_episodes`]): the
/// fine-tuned policy against its clone, paired, before the export. 500 resolves a difference of
/// about 1.5 points at 97-99% success (a McNemar test on ~15 discordant starts) for about two
/// minutes of evaluation on two cores; the 30 selection starts of every checkpoint cannot rank
/// files at 97-100% (docs/experiments.md, session 14).
pub const FINETUNE_GUARD_EPISODES: u32 = 500;

/// The most guard starts (they are drawn from the selection range, 1,000,000 seeds wide).
pub const MAX_GUARD_EPISODES: u32 = 100_000;

/// The most screening starts of `start.failed_starts` (the starting policy runs every one of them
/// before training: 100,000 Stack episodes are about 15 million environment steps).
pub const MAX_SCREEN_STARTS: u32 = 100_000;

/// The transition budget of the learner from demonstrations on Grasp, StackInHand and Stack: the
/// Grasp ablation's `no-norm` row, 47/50 and 46/50 for seeds 0 and 1 (docs/experiments.md).
pub const DEMOS_TRANSITIONS: u64 = 20_000;

/// The budget of the learner from demonstrations on Reach: seeds 0, 1, 2 score 98.5-100% over 200
/// starts (docs/experiments.md, session 7).
pub const REACH_DEMOS_TRANSITIONS: u64 = 10_000;

/// Reach's checkpoint (and selection) interval with the learner from demonstrations: 50-step
/// episodes, so a checkpoint every 50 episodes.
pub const REACH_DEMOS_CHECKPOINT_EVERY: u64 = 2_500;

/// What `trainer train --task T` runs without a settings file or a learner flag: the one
/// definition of each task's default pipeline and budget, for every front end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskDefault {
    /// The preset applied to the settings.
    pub preset: PresetArg,
    /// Transitions per seed (of the reinforcement-learning stage).
    pub transitions: u64,
    /// The checkpoint interval, where it is not the settings' default.
    pub checkpoint_every: Option<u64>,
    /// The seed when none is given: 1 on Grasp and Stack, whose clone stages' member seeds are
    /// written for pipeline seed 1 (the shipped files' seed; seed 0 would make members' seeds
    /// negative, [`crate::pipeline::clone_members`]), else 0.
    pub seed: u64,
}

impl TaskArg {
    /// The task's default pipeline: on the manipulation tasks the clone stage and the fine-tune
    /// that keeps it ([`PresetArg::Finetune`], guarded against its clone; the clone stage is the
    /// shipped file's, [`CloneStage::for_task`]: on Grasp an ensemble and its distillation at
    /// seed 1, on Stack one clone at seed 9); on Reach, whose
    /// demonstrations are solved by a few thousand transitions, the learner from demonstrations.
    pub fn default_pipeline(self) -> TaskDefault {
        match self {
            TaskArg::Reach => TaskDefault {
                preset: PresetArg::Demos,
                transitions: REACH_DEMOS_TRANSITIONS,
                checkpoint_every: Some(REACH_DEMOS_CHECKPOINT_EVERY),
                seed: 0,
            },
            TaskArg::StackInHand => TaskDefault {
                preset: PresetArg::Finetune,
                transitions: FINETUNE_TRANSITIONS,
                checkpoint_every: None,
                seed: 0,
            },
            TaskArg::Grasp => TaskDefault {
                preset: PresetArg::Finetune,
                transitions: FINETUNE_TRANSITIONS,
                checkpoint_every: None,
                seed: 1,
            },
            // The seed of the shipped file's clone: of the close-start recipe's two measured
            // seeds (8, 9), the one whose clone solved more development starts (docs/experiments.md,
            // session 37).
            TaskArg::Stack => TaskDefault {
                preset: PresetArg::Finetune,
                transitions: FINETUNE_TRANSITIONS,
                checkpoint_every: None,
                seed: 9,
            },
        }
    }
}

impl TrainSettings {
    /// The settings of `trainer train --task T` without a settings file or a learner flag
    /// ([`TaskArg::default_pipeline`] over the defaults, with the task's own reward).
    pub fn for_task(task: TaskArg) -> TrainSettings {
        let mut s = TrainSettings {
            task,
            ..TrainSettings::default()
        };
        if task != TaskArg::Reach {
            s.reward = RewardArg::TaskDefault;
        }
        s.out = PathBuf::from(format!("runs/{}", format!("{task:?}").to_lowercase()));
        let d = task.default_pipeline();
        d.preset.apply(&mut s);
        s.transitions = d.transitions;
        s.seeds = vec![d.seed];
        if let Some(c) = d.checkpoint_every {
            s.checkpoint_every = c;
        }
        s
    }
}

impl PresetArg {
    /// Applies the preset to `s`'s learner settings.
    pub fn apply(self, s: &mut TrainSettings) {
        match self {
            PresetArg::Paper => {
                let plain = RunConfig::default();
                s.run.td3 = plain.td3;
                s.run.n_step = plain.n_step;
                s.run.demos = plain.demos;
                s.run.noise.correlation = 0.0;
                s.run.noise.scale.clear();
                s.run.ddpg.action_l2 = 0.0;
                s.run.obs_norm.frozen_from_demos = false;
                s.demo_files.clear();
                s.record_demos = 0;
            }
            PresetArg::Finetune => {
                if s.demo_files.is_empty() && s.record_demos == 0 {
                    s.record_demos = 200;
                }
                let task = s.task;
                s.clone.get_or_insert_with(|| CloneStage::for_task(task));
                s.features = true;
                s.run.demos = crate::learn::DemoDataConfig {
                    fraction: 0.25,
                    bc_weight: 5.0,
                    q_filter: false,
                    pretrain_updates: 0,
                    q_normalisation: 2.5,
                    pretrain_actor_lr: None,
                };
                s.run.critic_warmup_updates = 10_000;
                s.guard_episodes = FINETUNE_GUARD_EPISODES;
                s.run.updates_per_step = 2;
                s.run.actor_adam.lr = 3e-5;
                s.run.ddpg.actor_hidden = vec![256, 256];
                s.run.obs_norm.enabled = false;
                s.run.obs_norm.frozen_from_init = false;
                if s.task != TaskArg::Reach {
                    s.run.ddpg.gamma = 0.98;
                }
            }
            PresetArg::Demos => {
                if s.demo_files.is_empty() && s.record_demos == 0 {
                    s.record_demos = 200;
                }
                s.run.demos = crate::learn::DemoDataConfig {
                    fraction: 0.25,
                    bc_weight: 1.0,
                    q_filter: false,
                    pretrain_updates: 20_000,
                    q_normalisation: 2.5,
                    pretrain_actor_lr: Some(3e-4),
                };
                s.run.actor_adam.lr = 3e-5;
                if s.task != TaskArg::Reach {
                    s.run.ddpg.gamma = 0.98;
                }
            }
        }
    }
}
