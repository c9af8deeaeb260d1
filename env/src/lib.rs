//! The simulated world of the paper: a Kinova Jaco arm with a 3-finger hand and two Duplo bricks on a
//! table, in MuJoCo 3.17.0 through `mujoco-rs`.
//!
//! - [`Scene`] compiles the model once ([`scene`]); it is shared (`Arc<MjModel>`, `Sync`) by every
//!   [`JacoEnv`], each of which owns one `MjData`: one environment per thread scales across cores.
//! - [`JacoEnv`] is the environment: [`JacoEnv::reset`] from a seed (the start states: [`random_start`]), [`JacoEnv::step`] with a 9-D action in
//!   [-1, 1], [`JacoEnv::snapshot`] / [`JacoEnv::restore`].
//! - [`Task`] (Grasp, StackInHand, Stack, Reach) fixes the start states and success; [`Reward`] is one of
//!   the paper's reward functions, built from the reach/grasp/stack [`Predicates`] ([`rewards`]).
//! - The observation ([`observation`]) follows `dex_runtime::interface::OBSERVATION_FIELDS` exactly.
//! - [`Demonstrator`] is a scripted state-based controller that solves the tasks ([`demo`]);
//!   [`MarkovDemonstrator`] decides from the current state alone, an oracle for cloning and DAgger
//!   ([`markov_demo`]).
//! - [`StartStates`] makes training starts under a [`StartScheme`]: original, in-hand mixture, or
//!   states along demonstrations ([`start_states`]).
//! - [`evaluate`]: the success rate of a policy file run through the `dex-runtime` evaluator (the
//!   code a controller runs) on these tasks; [`seeds`]: each episode's start seed and the named seed
//!   ranges of the evaluations; [`parallel`]: independent items on several threads, results in
//!   item order.
//!
//! Not here: rendering, the learner, and the real robot's CAN side.

pub mod contacts;
pub mod demo;
pub mod environment;
pub mod error;
pub mod evaluate;
pub mod fk_constants;
pub mod kinematics;
pub mod markov_demo;
pub mod observation;
pub mod paired;
pub mod paired_power;
pub mod parallel;
pub mod random_start;
pub mod rewards;
pub mod rng;
pub mod scene;
pub mod seeds;
pub mod start_states;
pub mod tasks;

pub use demo::{Demonstrator, Phase};
pub use environment::{EnvConfig, EnvSnapshot, JacoEnv, StepOutcome};
pub use error::EnvError;
pub use markov_demo::{MarkovDemonstrator, MarkovPhase};
pub use observation::Observation;
pub use rewards::{Predicates, Reward, RewardState};
pub use scene::{AssetPaths, Scene};
pub use start_states::{Demonstration, Handover, Revisits, StartKind, StartScheme, StartStates};
pub use tasks::Task;
