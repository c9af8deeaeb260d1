//! The Jaco cell as the learner sees it: glue between `dex-env` and the learner's traits.
//!
//! - [`jaco`]: the environment behind the learner's [`crate::learn::Env`] trait.
//! - [`policy_demo`]: a policy file as the demonstration of the start-state scheme.
//! - [`proposal_pair`]: an IBRL run's actor and proposal as one teacher.
//! - [`run_folder`]: a `trainer train` seed folder read back (settings, last checkpoint).
//! - [`critic_ranking`]: whether a run's critic orders actions as rollouts in the simulator do.

pub mod critic_ranking;
pub mod jaco;
pub mod policy_demo;
pub mod proposal_pair;
pub mod run_folder;
