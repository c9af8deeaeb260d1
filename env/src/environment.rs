//! The environment: reset from a seed, step with a 9-D action, snapshot and restore.

use std::f64::consts::PI;
use std::sync::Arc;

use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};
use mujoco_rs::prelude::*;

use super::demo::{Demonstrator, Phase};
use super::error::EnvError;
use super::kinematics::{down_rotation, pinch_pose, solve_ik};
use super::observation::{Observation, write_observation};
use super::rewards::{Predicates, Reward, RewardState};
use super::rng::SeedRng;
use super::scene::{ARM_JOINTS, SUBSTEPS, Scene};
use super::tasks::Task;

/// The arm configuration that start-state inverse kinematics begins from: hand above the workspace,
/// pointing down, elbow up.
pub const NOMINAL_ARM_QPOS: [f64; ARM_JOINTS] = [0.0, 3.6, 1.3, -1.6, 1.6, 0.0];
/// Half-width of the square (centred on the table origin) where bricks and the hand start, metres.
pub const START_XY_RANGE: f64 = 0.1;
/// Bricks start with their centres at least this far apart (their footprints' circumradius is 3.6 cm).
pub const MIN_BRICK_SPACING: f64 = 0.08;
/// Range of the finger joints' start positions (radians; fully open is 0.15, closed ~1.35).
pub const START_FINGER_RANGE: (f64, f64) = (0.15, 0.9);
/// Height of the pinch site above brick 1's origin at which the demonstrator closes the fingers.
pub const GRASP_DEPTH: f64 = 0.012;
/// Control steps the StackInHand start may spend picking brick 1 up (not part of the episode).
pub const PICK_UP_STEPS: u32 = 120;
const MAX_START_ATTEMPTS: u32 = 50;

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
#[derive(Debug, Clone, PartialEq)]
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

    /// Starts a new episode from the start-state distribution of the task, drawn from `seed` alone.
    pub fn reset(&mut self, seed: u64) -> Result<Observation, EnvError> {
        self.reset_with_start(seed, self.config.task)
    }

    /// Starts a new episode of the configured task from the start-state distribution of `start`
    /// (e.g. a Stack episode from the StackInHand start, brick 1 already grasped and lifted).
    pub fn reset_with_start(&mut self, seed: u64, start: Task) -> Result<Observation, EnvError> {
        let mut rng = SeedRng::new(seed);
        let task = start;
        for _ in 0..MAX_START_ATTEMPTS {
            if self.try_start_state(&mut rng, task)? {
                self.steps = 0;
                self.data.set_time(0.0);
                self.data.forward();
                self.refresh_observation();
                return Ok(self.observation);
            }
        }
        Err(EnvError::StartState {
            task,
            attempts: MAX_START_ATTEMPTS,
        })
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

    fn refresh_observation(&mut self) {
        write_observation(&self.data, self.scene.ids(), &mut self.observation);
    }

    /// One attempt at a start state; `Ok(false)` means "rejected, draw again".
    fn try_start_state(&mut self, rng: &mut SeedRng, task: Task) -> Result<bool, EnvError> {
        let ids = *self.scene.ids();
        self.data.reset();
        // Bricks: uniform in the start square with random yaw, far enough apart not to overlap.
        let b1 = [
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
        ];
        let b2 = [
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
        ];
        let (yaw1, yaw2) = (rng.uniform(-PI, PI), rng.uniform(-PI, PI));
        if (b1[0] - b2[0]).hypot(b1[1] - b2[1]) < MIN_BRICK_SPACING {
            return Ok(false);
        }
        set_free(&mut self.data, ids.brick1_qpos, [b1[0], b1[1], 0.0], yaw1);
        set_free(&mut self.data, ids.brick2_qpos, [b2[0], b2[1], 0.0], yaw2);
        // Hand: pinch site at a random point above the table, pointing down, random yaw.
        let (zlo, zhi) = task.start_height();
        let target = [
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
            rng.uniform(-START_XY_RANGE, START_XY_RANGE),
            rng.uniform(zlo, zhi),
        ];
        let hand_yaw = rng.uniform(-PI, PI);
        let fingers = rng.uniform(START_FINGER_RANGE.0, START_FINGER_RANGE.1);
        {
            let qpos = self.data.qpos_mut();
            for (&adr, &q) in ids.joint_qpos.iter().zip(NOMINAL_ARM_QPOS.iter()) {
                if let Some(slot) = qpos.get_mut(adr) {
                    *slot = q;
                }
            }
            for &adr in &ids.joint_qpos[ARM_JOINTS..] {
                if let Some(slot) = qpos.get_mut(adr) {
                    *slot = if task == Task::StackInHand {
                        START_FINGER_RANGE.0
                    } else {
                        fingers
                    };
                }
            }
        }
        let (pos_err, rot_err) = solve_ik(
            &mut self.data,
            &ids,
            &nalgebra::Vector3::from(target),
            &down_rotation(hand_yaw),
            100,
        );
        if pos_err > 0.005 || rot_err > 0.05 {
            return Ok(false);
        }
        if task == Task::StackInHand {
            self.data.forward();
            return self.pick_up_brick1();
        }
        Ok(true)
    }

    /// Lets the scripted demonstrator pick brick 1 up (Grasp script) and checks that it is really held:
    /// lifted above 5 cm and within 3 cm of the pinch site after the hand has come to rest.
    fn pick_up_brick1(&mut self) -> Result<bool, EnvError> {
        let saved = self.config;
        self.config = EnvConfig::new(Task::Grasp);
        let mut demo = Demonstrator::new(Task::Grasp);
        let mut lifted_for = 0;
        let mut held = false;
        for _ in 0..PICK_UP_STEPS {
            let action = demo.act(self);
            let step = self.step(&action);
            if step.is_err() {
                break;
            }
            let s = self.reward_state();
            let d = [
                s.brick1_pos[0] - s.pinch[0],
                s.brick1_pos[1] - s.pinch[1],
                s.brick1_pos[2] - s.pinch[2],
            ];
            let near = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() < 0.03;
            if demo.phase() == Phase::Lift && s.brick1_pos[2] > 0.05 && near {
                lifted_for += 1;
                if lifted_for >= 8 {
                    held = true;
                    break;
                }
            }
        }
        self.config = saved;
        Ok(held)
    }
}

/// Writes a free joint's pose: position and a rotation of `yaw` about the vertical.
fn set_free(data: &mut MjData<Arc<MjModel>>, adr: usize, pos: [f64; 3], yaw: f64) {
    let (s, c) = (0.5 * yaw).sin_cos();
    let pose = [pos[0], pos[1], pos[2], c, 0.0, 0.0, s];
    let qpos = data.qpos_mut();
    for (k, v) in pose.iter().enumerate() {
        if let Some(slot) = qpos.get_mut(adr + k) {
            *slot = *v;
        }
    }
}
