//! The environment: reset from a seed, step with a 9-D action, snapshot and restore.

use std::sync::Arc;

use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};
use mujoco_rs::prelude::*;

use super::error::EnvError;
use super::kinematics::pinch_pose;
use super::observation::{Observation, write_observation};
use super::rewards::{Predicates, Reward, RewardState};
use super::scene::{SUBSTEPS, Scene};
use super::tasks::Task;

/// What an environment simulates: the task, the reward and the episode length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EnvConfig {
    /// The task (start-state distribution and success definition).
    pub task: Task,
    /// The reward function.
    pub reward: Reward,
    /// Control steps per episode; `done` is set when this many steps have been taken.
    pub episode_steps: u32,
}

impl EnvConfig {
    /// The task with its own reward and episode length.
    pub const fn new(task: Task) -> Self {
        Self {
            task,
            reward: task.default_reward(),
            episode_steps: task.episode_steps(),
        }
    }

    /// The same configuration with another reward.
    pub const fn with_reward(mut self, reward: Reward) -> Self {
        self.reward = reward;
        self
    }
}

impl Default for EnvConfig {
    /// Stack with the sparse stack reward, 150 steps.
    fn default() -> Self {
        Self::new(Task::Stack)
    }
}

/// The result of one control step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// Observation after the step.
    pub observation: Observation,
    /// Reward of the state after the step.
    pub reward: f32,
    /// The episode's step budget is used up (a time limit, not a terminal state).
    pub done: bool,
    /// The task's success predicate holds after the step (evaluation reads it at the last step).
    pub success: bool,
    /// The reach, grasp and stack predicates after the step.
    pub predicates: Predicates,
}

/// A full copy of the simulation state, cheap to restore (MuJoCo's `mjSTATE_INTEGRATION`).
/// Serialisable so that a learner can keep states in its checkpoint; restoring one of another
/// scene's size is refused ([`EnvError::Snapshot`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvSnapshot {
    state: Box<[f64]>,
    steps: u32,
}

impl EnvSnapshot {
    /// Control steps taken in the episode when the snapshot was made.
    pub fn steps(&self) -> u32 {
        self.steps
    }
}

const STATE_SPEC: u32 = MjtState::mjSTATE_INTEGRATION as u32;

/// One Jaco stacking environment: its own `MjData` over the scene's shared model.
///
/// Actions are 9 numbers in [-1, 1] (arm joints 1-6, fingers 1-3); component `i` is clipped to [-1, 1]
/// and multiplied by `ACTION_JOINTS[i].scale` to give the velocity actuator's target. Non-finite actions
/// are rejected. Each step runs 25 physics steps of 2 ms.
#[derive(Debug)]
pub struct JacoEnv {
    scene: Scene,
    data: MjData<Arc<MjModel>>,
    config: EnvConfig,
    steps: u32,
    observation: Observation,
}

impl JacoEnv {
    /// A new environment for `config` over the shared `scene`; call [`JacoEnv::reset`] before stepping.
    pub fn new(scene: &Scene, config: EnvConfig) -> Self {
        let mut env = Self {
            scene: scene.clone(),
            data: scene.make_data(),
            config,
            steps: 0,
            observation: [0.0; OBS_DIM],
        };
        env.data.forward();
        env.refresh_observation();
        env
    }

    /// The configuration.
    pub fn config(&self) -> &EnvConfig {
        &self.config
    }

    /// Changes task, reward or episode length; takes effect at the next reset.
    pub fn set_config(&mut self, config: EnvConfig) {
        self.config = config;
    }

    /// The scene this environment simulates.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The MuJoCo state (read-only), e.g. for the demonstrator or a renderer.
    pub fn data(&self) -> &MjData<Arc<MjModel>> {
        &self.data
    }

    /// Control steps taken since the last reset.
    pub fn steps_taken(&self) -> u32 {
        self.steps
    }

    /// The current observation.
    pub fn observation(&self) -> &Observation {
        &self.observation
    }

    /// Applies `action` for one 50 ms control step.
    pub fn step(&mut self, action: &[f32; ACT_DIM]) -> Result<StepOutcome, EnvError> {
        if let Some((index, &value)) = action.iter().enumerate().find(|(_, a)| !a.is_finite()) {
            return Err(EnvError::NonFiniteAction { index, value });
        }
        let ctrl = self.data.ctrl_mut();
        for ((c, &a), joint) in ctrl.iter_mut().zip(action).zip(ACTION_JOINTS) {
            *c = f64::from((a.clamp(-1.0, 1.0) * joint.scale).clamp(joint.min, joint.max));
        }
        for _ in 0..SUBSTEPS {
            self.data.step();
        }
        if self.data.qpos().iter().any(|q| !q.is_finite()) {
            return Err(EnvError::Diverged {
                time: self.data.time(),
            });
        }
        // mj_step leaves positions one integration ahead of the kinematics; bring them level.
        self.data.kinematics();
        self.data.com_pos();
        self.steps = self.steps.saturating_add(1);
        self.refresh_observation();
        let state = self.reward_state();
        let predicates = state.predicates();
        Ok(StepOutcome {
            observation: self.observation,
            reward: self.config.reward.evaluate(&state, predicates) as f32,
            done: self.steps >= self.config.episode_steps,
            success: self.config.task.is_success(predicates),
            predicates,
        })
    }

    /// The positions the rewards are computed from.
    pub fn reward_state(&self) -> RewardState {
        let ids = self.scene.ids();
        let pinch: [f64; 3] = pinch_pose(&self.data, ids).0.into();
        let xpos = self.data.xpos();
        RewardState {
            pinch,
            brick1_pos: xpos.get(ids.brick1_body).copied().unwrap_or([0.0; 3]),
            brick2_pos: xpos.get(ids.brick2_body).copied().unwrap_or([0.0; 3]),
            brick2_mat: self
                .data
                .xmat()
                .get(ids.brick2_body)
                .copied()
                .unwrap_or([0.0; 9]),
        }
    }

    /// The predicates of the current state.
    pub fn predicates(&self) -> Predicates {
        self.reward_state().predicates()
    }

    /// Copies the simulation state and the step counter.
    pub fn snapshot(&self) -> EnvSnapshot {
        EnvSnapshot {
            state: self.data.state(STATE_SPEC),
            steps: self.steps,
        }
    }

    /// Continues from `snapshot` (made by an environment over the same scene); stepping on gives exactly
    /// what the original would have given.
    pub fn restore(&mut self, snapshot: &EnvSnapshot) -> Result<Observation, EnvError> {
        self.data
            .set_state(&snapshot.state, STATE_SPEC)
            .map_err(|source| EnvError::Snapshot { source })?;
        self.data.forward();
        self.steps = snapshot.steps;
        self.refresh_observation();
        Ok(self.observation)
    }

    /// Makes the current state the first of a new episode: the step counter goes back to zero (the
    /// state itself is kept). Used when a state reached by simulation is handed to the learner.
    pub fn begin_episode(&mut self) -> Observation {
        self.steps = 0;
        self.observation
    }

    /// The MuJoCo state, writable: for the start-state sampler ([`super::random_start`]), which
    /// poses the bricks and the arm before [`JacoEnv::settle_new_episode`].
    pub(crate) fn data_mut(&mut self) -> &mut MjData<Arc<MjModel>> {
        &mut self.data
    }

    /// The scene beside the simulation state, for queries that read one and write the other.
    pub(crate) fn scene_and_data_mut(&mut self) -> (&Scene, &mut MjData<Arc<MjModel>>) {
        (&self.scene, &mut self.data)
    }

    /// Makes the posed state the first of a new episode: clock and step counter at zero, kinematics
    /// and observation brought level with the state.
    pub(crate) fn settle_new_episode(&mut self) -> Observation {
        self.steps = 0;
        self.data.set_time(0.0);
        self.data.forward();
        self.refresh_observation();
        self.observation
    }

    fn refresh_observation(&mut self) {
        write_observation(&self.data, self.scene.ids(), &mut self.observation);
    }
}
