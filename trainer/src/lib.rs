//! The simulated Jaco stacking world and the DPG-R / ADPG-R learner.
//!
//! Filled in by the environment and trainer issues; see `ARCHITECTURE.md`.
//!
//! - [`env`]: the MuJoCo Jaco stacking environment — scene, tasks, the paper's rewards, the observation of
//!   `dex_runtime::interface`, and a scripted demonstrator. It links MuJoCo 3.17.0, which
//!   `scripts/setup-mujoco.sh` fetches once; see `docs/environment.md`.

pub mod env;
pub mod evaluate;
pub mod export;
pub mod jaco;
pub mod learn;
pub mod plot;
