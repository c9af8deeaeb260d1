//! Run pipelines: what turns settings into a run folder, and a run folder into results.
//!
//! - [`train_settings`]: the settings of a training run (defaults < TOML file < flags), validated
//!   once, and kept in each run folder as `settings.toml`.
//! - [`train_run`]: the training pipeline of a run folder, for any front end: per seed train with
//!   checkpoints (fresh or resumed), select the best checkpoint, export and evaluate it; progress
//!   as events.
//! - [`cloning`]: behaviour cloning of demonstration files into a policy file; [`imitation`]:
//!   cloning plus DAgger rounds with the Markov demonstrator as the oracle (`trainer imitate`);
//!   [`clone_members`]: the clone stage as an ensemble of imitation runs distilled into one
//!   network (members, their seeds from the pipeline seed, the distillation's settings).
//! - [`self_imitation`]: a policy file's successful noisy episodes as cloning data labelled with
//!   their executed actions (`trainer imitate --self-imitation`).
//! - [`rollout_teacher`]: the winning branches of a policy file's failed episodes, found by
//!   rollouts from simulator snapshots, as cloning data (`trainer imitate --rollout-teacher`).
//! - [`file_actor`]: a policy file's network as a trainable actor and back (the fine-tunes').
//! - [`run_lock`]: one trainer per run folder (an advisory lock the OS drops with the process).
//! - [`run_plots`]: a run folder's learning curves, drawn by [`plot`] (mean and min-max band over
//!   seeds, like the paper's figures).

pub mod clone_members;
pub mod cloning;
pub mod file_actor;
pub mod group_pg;
pub mod imitation;
pub mod plot;
pub mod rollout_teacher;
pub mod run_lock;
pub mod run_plots;
pub mod self_imitation;
pub mod stall_starts;
pub mod train_run;
pub mod train_settings;
