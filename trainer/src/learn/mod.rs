//! The DPG-R / ADPG-R learner of Popov et al. (2017), "Data-efficient Deep Reinforcement Learning for
//! Dexterous Manipulation".
//!
//! - [`nets`]: MLPs with hand-written backpropagation over preallocated buffers, on a single-threaded GEMM
//!   ([`kernel`]; the engine choice is measured in docs/benchmarks.md).
//! - [`adam`]: Adam with per-worker first moments and one shared second moment.
//! - [`bc`]: behaviour cloning of demonstrations (the diagnostic and the fine-tuning start).
//! - [`norm`]: optional observation normalisation, foldable into the actor for export.
//! - [`quantise`]: quantisation-aware training of the actor (int8-grid weights, straight-through).
//! - [`replay`]: uniform ring-buffer replay. [`ddpg`]: the DDPG gradients and target networks.
//! - Beyond the paper, each off by default: [`demo_data`] (a demonstration buffer, a batch fraction
//!   from it and a Q-filtered cloning term), [`td3`] (twin critics, target smoothing, delayed actor
//!   updates), [`n_step`] (n-step returns, correct at time limits), [`noise`] (temporally
//!   correlated exploration with a per-joint scale), the action penalty in [`ddpg::ActorLoss`] and
//!   [`residual`] (a residual actor on a frozen starting policy, one plain MLP).
//! - [`env`](mod@env): the [`Env`] trait the learner drives, and a toy [`PointMass`] task for tests.
//! - [`trainer`]: [`Trainer`] runs W worker threads (W = 1 is DPG-R) with R updates per environment step,
//!   evaluates on the paper's schedule and streams [`EvalRecord`]s; [`checkpoint`] saves and restores it.
//!
//! - [`distributed`]: ADPG-R across processes (a parameter server and worker ranks; MPI behind
//!   the `mpi` feature).
//!
//! Not here: the command line, plots and policy export (they use [`Trainer::actor`] and
//! [`nets::Mlp::layers`]), and the Jaco environment itself.

pub mod adam;
pub mod bc;
pub mod checkpoint;
pub mod ddpg;
pub mod demo_data;
pub mod distributed;
pub mod env;
pub mod ibrl;
pub mod kernel;
pub mod n_step;
pub mod nets;
pub mod noise;
pub mod norm;
pub mod quantise;
pub mod replay;
pub mod residual;
pub mod rng;
pub mod td3;
pub mod trainer;

pub use adam::AdamConfig;
pub use ddpg::{ActorLoss, DdpgConfig, Networks, TargetUpdate};
pub use demo_data::{DemoBuffer, DemoDataConfig, DemoTransition};
pub use env::{Env, PointMass, PointMassConfig, Step};
pub use kernel::Engine;
pub use norm::{Normalizer, ObsNormConfig};
pub use quantise::QuantiseConfig;
pub use rng::Rng;
pub use td3::Td3Config;
pub use trainer::{
    EvalConfig, EvalRecord, Event, NoiseConfig, Progress, ReplayConfig, RunConfig, RunSummary,
    Trainer,
};

/// Everything that can go wrong in the learner.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LearnError {
    /// A network shape is unusable.
    #[error("bad network shape: {0}")]
    BadNetwork(&'static str),
    /// A buffer has the wrong length.
    #[error("{what} has length {got}, expected {expected}")]
    Shape {
        /// Which buffer.
        what: &'static str,
        /// Length required.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// An update was asked for with an empty replay buffer.
    #[error("the replay buffer is empty")]
    EmptyReplay,
    /// A configuration value is out of range.
    #[error("invalid configuration: {field}: {why}")]
    Config {
        /// The offending field.
        field: &'static str,
        /// What is wrong with it.
        why: &'static str,
    },
    /// The environment's dimensions differ from the trainer's.
    #[error("environment has obs/act dims {got:?}, the trainer was built for {expected:?}")]
    EnvMismatch {
        /// Trainer's (obs, act) dims.
        expected: (usize, usize),
        /// Environment's (obs, act) dims.
        got: (usize, usize),
    },
    /// A worker thread panicked or a lock was poisoned.
    #[error("a worker thread failed: {0}")]
    Worker(&'static str),
    /// Reading or writing a checkpoint failed.
    #[error("checkpoint I/O on {path}: {source}")]
    Io {
        /// File involved.
        path: std::path::PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A checkpoint file is damaged, from another version, or from an incompatible configuration.
    #[error("bad checkpoint: {0}")]
    BadCheckpoint(&'static str),
    /// A distributed run failed (a rank lost, MPI unusable, bad settings).
    #[error(transparent)]
    Distributed(#[from] distributed::DistributedError),
}
