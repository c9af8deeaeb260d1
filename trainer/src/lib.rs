//! `dex-trainer`: the simulated Jaco stacking world, the DPG-R / ADPG-R learner, and the path from a
//! trained actor to a policy file.
//!
//! - [`mod@env`]: the MuJoCo Jaco stacking environment: scene, tasks, the paper's rewards, the
//!   observation of `dex_runtime::interface`, and a scripted demonstrator. It links MuJoCo 3.17.0,
//!   which `scripts/setup-mujoco.sh` fetches once; see `docs/environment.md`.
//! - [`learn`]: networks, Adam with a shared second moment, replay, DDPG and the multi-worker
//!   [`learn::Trainer`]; see `docs/learner.md`.
//! - [`jaco`]: the environment behind the learner's [`learn::Env`] trait.
//! - [`export`]: a trained actor as a `dex-policy` file; [`evaluate`]: the success rate of such a
//!   file run through the `dex-runtime` evaluator, the code a controller runs.
//! - [`demos`]: demonstrations recorded as data (versioned, checksummed files); [`cloning`]: behaviour
//!   cloning of them into a policy file; [`imitation`]: cloning plus DAgger rounds with the Markov
//!   demonstrator as the oracle, the learner that solves Grasp and StackInHand.
//! - [`plot`]: learning curves like the paper's (mean and min-max band over seeds).
//! - [`atomic_write`]: the one atomic, durable file write (temporary file, fsync, rename, fsync of
//!   the folder) behind every file that must survive a crash: checkpoints, demo and policy files,
//!   run settings and logs.
//! - [`run_lock`]: one trainer per run folder (an advisory lock the OS drops with the process).
//! - [`train_settings`]: the settings of a training run (defaults < TOML file < flags), validated
//!   once, and kept in each run folder as `settings.toml`.
//! - [`train_run`]: the training pipeline of a run folder, for any front end: per seed train with
//!   checkpoints (fresh or resumed), select the best checkpoint, export and evaluate it; progress
//!   as events. [`run_plots`]: a run folder's learning curves.
//!
//! The `trainer` binary is a front end: it turns flags into [`train_settings::TrainSettings`],
//! calls these, and prints progress (train, eval, plot, export, figure, demos, clone, imitate).

pub mod atomic_write;
pub mod cloning;
pub mod demos;
/// The environment (crate `dex-env`, re-exported so `dex_trainer::env::*` keeps its paths).
pub use dex_env as env;
/// The runtime's evaluator on the environment (`dex_env::evaluate`).
pub use dex_env::evaluate;
pub mod export;
pub mod imitation;
pub mod int8_export;
pub mod jaco;
pub mod learn;
pub mod plot;
pub mod policy_demo;
pub mod policy_import;
pub mod result_record;
pub mod run_lock;
pub mod run_plots;
pub mod train_run;
pub mod train_settings;
