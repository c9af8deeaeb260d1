//! Errors of the environment.

use std::path::PathBuf;

use mujoco_rs::error::{MjDataError, MjEditError};

use super::tasks::Task;

/// Everything that can go wrong when building or stepping the Jaco environment.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EnvError {
    /// The Jaco / Duplo MJCF files are not where the scene expects them.
    #[error(
        "MuJoCo assets not found: {path} is missing; run `scripts/setup-mujoco.sh` from the repository root"
    )]
    AssetsMissing {
        /// The file that was looked for.
        path: PathBuf,
    },
    /// MuJoCo refused to parse, attach or compile the scene.
    #[error("MuJoCo could not build the scene while {stage}")]
    Scene {
        /// What was being done (parsing the scene, attaching the hand, compiling).
        stage: &'static str,
        /// MuJoCo's own error.
        #[source]
        source: MjEditError,
    },
    /// A named element the environment relies on is absent from the compiled model.
    #[error("the compiled scene has no {kind} named `{name}`")]
    MissingElement {
        /// Element kind (body, joint, site, actuator).
        kind: &'static str,
        /// The name that was looked up.
        name: &'static str,
    },
    /// An action component was NaN or infinite.
    #[error(
        "action[{index}] = {value} is not finite; actions must be finite (out-of-range values are clipped)"
    )]
    NonFiniteAction {
        /// Index of the first offending component.
        index: usize,
        /// Its value.
        value: f32,
    },
    /// No valid start state could be sampled (e.g. the brick kept slipping out of the hand).
    #[error("no valid start state for {task:?} after {attempts} attempts")]
    StartState {
        /// The task whose start state was sampled.
        task: Task,
        /// How many samples were tried.
        attempts: u32,
    },
    /// The simulation produced non-finite positions (physics blew up).
    #[error("the simulation diverged at t = {time:.3} s (non-finite state)")]
    Diverged {
        /// Simulated time of the failure.
        time: f64,
    },
    /// A snapshot did not fit this model.
    #[error("cannot restore the snapshot")]
    Snapshot {
        /// MuJoCo-rs's error.
        #[source]
        source: MjDataError,
    },
    /// A close start's largest brick spacing ([`crate::random_start::check_close_spacing`]) is
    /// outside its range.
    #[error(
        "close-start spacing {max_spacing} m is outside (0.08, 0.3]: it must be above the bricks' \
         least spacing (8 cm) and at most 0.3 m (the start square's diagonal is 0.28 m)"
    )]
    CloseSpacing {
        /// The spacing given, metres.
        max_spacing: f64,
    },
    /// A start-state scheme's setting is out of range, or it could not make a start.
    #[error("start-state scheme: {0}")]
    StartScheme(String),
}
