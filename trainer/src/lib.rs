//! `dex-trainer`: the simulated Jaco stacking world, the DPG-R / ADPG-R learner, and the path from a
//! trained actor to a policy file.
//!
//! - [`mod@env`]: the MuJoCo Jaco stacking environment: scene, tasks, the paper's rewards, the
//!   observation of `dex_runtime::interface`, and a scripted demonstrator. It links MuJoCo 3.17.0,
//!   which `scripts/setup-mujoco.sh` fetches once; see `docs/environment.md`. [`evaluate`]: the
//!   success rate of a policy file run through the `dex-runtime` evaluator, the code a controller
//!   runs.
//! - [`learn`]: the learner: networks, Adam with a shared second moment, replay, DDPG and the
//!   multi-worker [`learn::Trainer`]; see `docs/learner.md`.
//! - [`pipeline`]: run pipelines: the settings of a training run and its run folder (train,
//!   select, export, evaluate, resume), behaviour cloning and the imitation learner, the run lock,
//!   learning curves.
//! - [`files`]: files in and out: the one atomic durable write, demonstration files, policy export
//!   (f32 and int8), policy import for fine-tuning, result records.
//! - [`cell`]: the Jaco cell behind the learner's traits (the environment, a policy file as the
//!   demonstration of the start-state scheme).
//!
//! The `trainer` binary is a front end: it turns flags into
//! [`pipeline::train_settings::TrainSettings`], calls these, and prints progress (train, eval,
//! plot, export, figure, demos, clone, imitate).

/// The environment (crate `dex-env`, re-exported so `dex_trainer::env::*` keeps its paths).
pub use dex_env as env;
/// The runtime's evaluator on the environment (`dex_env::evaluate`).
pub use dex_env::evaluate;
pub mod cell;
pub mod files;
pub mod learn;
pub mod pipeline;
