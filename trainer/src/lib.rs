//! The simulated Jaco stacking world and the DPG-R / ADPG-R learner.
//!
//! Filled in by the environment and trainer issues; see `ARCHITECTURE.md`.

pub mod env;
pub mod evaluate;
pub mod export;
pub mod jaco;
pub mod learn;
pub mod plot;
