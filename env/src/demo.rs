//! The scripted demonstrator: a state machine over pinch-site targets, tracked by resolved-rate inverse
//! kinematics (damped least squares on `mj_jacSite`).
//!
//! Phases: approach above brick 1 while turning the hand to the brick's yaw and opening the fingers;
//! descend; close; lift; carry brick 1 over brick 2 (aligning brick 1's yaw with brick 2's); lower onto
//! the studs; release; retreat. Grasp ends holding the brick up; Reach ends with the pinch site at brick 1;
//! StackInHand starts at the carry phase.

use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS};

use nalgebra::{Rotation3, Vector2, Vector3, Vector6};

use super::environment::JacoEnv;
use super::kinematics::{
    angular, arm_jacobian, damped_least_squares, down_rotation, linear, pinch_pose, pose_error,
    xmat_rotation,
};
use super::scene::{ARM_JOINTS, BRICK_HEIGHT, GRASP_DEPTH};
use super::tasks::Task;

/// Height above the grasp point from which the hand descends, metres.
pub const APPROACH_HEIGHT: f64 = 0.07;
/// Pinch-site height the brick is lifted to (Grasp), metres.
pub const LIFT_HEIGHT: f64 = 0.12;
/// Height of brick 1 above the stacking site while carrying, metres.
pub const CARRY_CLEARANCE: f64 = 0.03;
/// Finger angle (rad) the hand pre-shapes to while approaching (0.15 open, 1.35 closed).
pub const PRESHAPE: f64 = 0.5;
/// Position gain of the resolved-rate controller, 1/s.
pub const POSITION_GAIN: f64 = 8.0;
/// Orientation gain, 1/s.
pub const ORIENTATION_GAIN: f64 = 6.0;
/// Angular speed limit of the hand, rad/s (below wrist joint 6's 0.838 rad/s).
pub const MAX_ANGULAR_SPEED: f64 = 0.7;
/// Speed limit of the pinch site, m/s.
pub const MAX_SPEED: f64 = 0.35;

/// Where the demonstrator is in its script.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Phase {
    /// Move above brick 1, turn to its yaw, open the fingers.
    Approach,
    /// Go down to the grasp point.
    Descend,
    /// Close the fingers.
    Close,
    /// Lift brick 1.
    Lift,
    /// Carry brick 1 above brick 2.
    Carry,
    /// Lower brick 1 onto brick 2.
    Lower,
    /// Open the fingers.
    Release,
    /// Move the hand up and away.
    Retreat,
}

/// A scripted controller for one episode; create a new one (or [`Demonstrator::restart`]) per episode.
#[derive(Debug, Clone)]
pub struct Demonstrator {
    task: Task,
    phase: Phase,
    timer: u32,
    anchor: [f64; 3],
    anchor_yaw: f64,
}

impl Demonstrator {
    /// A demonstrator for `task`, at its first phase.
    pub fn new(task: Task) -> Self {
        let mut d = Self {
            task,
            phase: Phase::Approach,
            timer: 0,
            anchor: [0.0; 3],
            anchor_yaw: 0.0,
        };
        d.restart();
        d
    }

    /// Back to the first phase (for a new episode).
    pub fn restart(&mut self) {
        self.phase = if self.task == Task::StackInHand {
            Phase::Carry
        } else {
            Phase::Approach
        };
        self.timer = 0;
    }

    /// Back to the phase that fits the environment's current state, for taking over an episode
    /// midway (e.g. from a learned policy): with brick 1 already in the closed hand it carries on
    /// lifting (Grasp) or carrying (StackInHand, Stack); otherwise it starts from the approach.
    pub fn restart_from_state(&mut self, env: &JacoEnv) {
        let ids = env.scene().ids();
        let data = env.data();
        let pinch: [f64; 3] = pinch_pose(data, ids).0.into();
        let b1 = data
            .xpos()
            .get(ids.brick1_body)
            .copied()
            .unwrap_or([0.0; 3]);
        let closed = ids.joint_qpos[ARM_JOINTS..]
            .iter()
            .map(|&a| data.qpos().get(a).copied().unwrap_or(0.0))
            .sum::<f64>()
            / 3.0
            > PRESHAPE + 0.2;
        let held = closed && Vector3::from(sub(&b1, &pinch)).norm() < 0.04 && b1[2] > 0.005;
        let phase = match (self.task, held) {
            (Task::Reach, _) | (_, false) => Phase::Approach,
            (Task::Grasp, true) => Phase::Lift,
            (Task::StackInHand | Task::Stack, true) => Phase::Carry,
        };
        self.enter(phase, env);
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    fn enter(&mut self, phase: Phase, env: &JacoEnv) {
        self.phase = phase;
        self.timer = 0;
        let (pinch, rot) = pinch_pose(env.data(), env.scene().ids());
        self.anchor = pinch.into();
        self.anchor_yaw = yaw_of(&rot);
    }

    /// The action for the environment's current state.
    pub fn act(&mut self, env: &JacoEnv) -> [f32; ACT_DIM] {
        let ids = env.scene().ids();
        let data = env.data();
        let (pinch, pinch_rot) = pinch_pose(data, ids);
        let pinch: [f64; 3] = pinch.into();
        let hand_yaw = yaw_of(&pinch_rot);
        let b1 = data
            .xpos()
            .get(ids.brick1_body)
            .copied()
            .unwrap_or([0.0; 3]);
        let b2 = data
            .xpos()
            .get(ids.brick2_body)
            .copied()
            .unwrap_or([0.0; 3]);
        let m1 = data
            .xmat()
            .get(ids.brick1_body)
            .copied()
            .unwrap_or([0.0; 9]);
        let m2 = data
            .xmat()
            .get(ids.brick2_body)
            .copied()
            .unwrap_or([0.0; 9]);
        let grasp_yaw = nearest_equivalent(yaw_of(&xmat_rotation(&m1)), hand_yaw);
        let stack_site = [
            b2[0] + m2[2] * BRICK_HEIGHT,
            b2[1] + m2[5] * BRICK_HEIGHT,
            b2[2] + m2[8] * BRICK_HEIGHT,
        ];
        // Hand yaw that turns brick 1 (held) to brick 2's yaw.
        let place_yaw =
            hand_yaw + wrap_half_pi(yaw_of(&xmat_rotation(&m2)) - yaw_of(&xmat_rotation(&m1)));
        let finger_vel: Vec<f64> = ids.joint_dof[ARM_JOINTS..]
            .iter()
            .map(|&a| data.qvel().get(a).copied().unwrap_or(0.0))
            .collect();
        let finger_pos: Vec<f64> = ids.joint_qpos[ARM_JOINTS..]
            .iter()
            .map(|&a| data.qpos().get(a).copied().unwrap_or(0.0))
            .collect();
        // Pre-shape: fingers to PRESHAPE rad (open enough for the brick's narrow side) while approaching.
        let preshape = (PRESHAPE - finger_pos.iter().sum::<f64>() / 3.0).clamp(-1.0, 1.0) * 4.0;
        let preshape = preshape.clamp(-1.0, 1.0);
        // Brick 1 counts as in the hand while its origin stays within 4 cm of the pinch site.
        let in_hand = Vector3::from(sub(&b1, &pinch)).norm() < 0.04;
        self.timer += 1;
        let mut speed = MAX_SPEED;

        let (target, yaw, fingers): ([f64; 3], f64, f64) = loop {
            match self.phase {
                Phase::Approach => {
                    let t = [b1[0], b1[1], b1[2] + GRASP_DEPTH + APPROACH_HEIGHT];
                    let e = sub(&t, &pinch);
                    if self.task != Task::Reach
                        && Vector3::from(e).norm() < 0.015
                        && (grasp_yaw - hand_yaw).abs() < 0.08
                    {
                        self.enter(Phase::Descend, env);
                        continue;
                    }
                    if self.task == Task::Reach && Vector3::from(e).norm() < 0.03 {
                        self.enter(Phase::Descend, env);
                        continue;
                    }
                    break (t, grasp_yaw, preshape);
                }
                Phase::Descend => {
                    let t = [b1[0], b1[1], b1[2] + GRASP_DEPTH];
                    if self.task != Task::Reach
                        && (Vector3::from(sub(&t, &pinch)).norm() < 0.005 || self.timer > 25)
                    {
                        self.enter(Phase::Close, env);
                        continue;
                    }
                    break (t, grasp_yaw, preshape);
                }
                Phase::Close => {
                    let t = self.anchor;
                    let settled = finger_vel.iter().all(|v| v.abs() < 0.05);
                    if (self.timer > 4 && settled) || self.timer > 30 {
                        self.enter(Phase::Lift, env);
                        continue;
                    }
                    break (t, self.anchor_yaw, 1.0);
                }
                Phase::Lift => {
                    let t = [self.anchor[0], self.anchor[1], LIFT_HEIGHT];
                    if self.timer > 12 && !in_hand {
                        // The grasp missed: try again.
                        self.enter(Phase::Approach, env);
                        continue;
                    }
                    if self.task != Task::Grasp && b1[2] > 0.035 {
                        self.enter(Phase::Carry, env);
                        continue;
                    }
                    break (t, self.anchor_yaw, 1.0);
                }
                Phase::Carry => {
                    if !in_hand {
                        // Dropped: pick it up again.
                        self.enter(Phase::Approach, env);
                        continue;
                    }
                    let want = [
                        stack_site[0],
                        stack_site[1],
                        stack_site[2] + CARRY_CLEARANCE,
                    ];
                    let e = sub(&want, &b1);
                    if Vector2::new(e[0], e[1]).norm() < 0.004
                        && e[2].abs() < 0.01
                        && (place_yaw - hand_yaw).abs() < 0.05
                    {
                        self.enter(Phase::Lower, env);
                        continue;
                    }
                    break (add(&pinch, &e), place_yaw, 1.0);
                }
                Phase::Lower => {
                    let xy = Vector2::new(stack_site[0] - b1[0], stack_site[1] - b1[1]).norm();
                    let dz = b1[2] - stack_site[2];
                    if (xy < 0.003 && dz < 0.007) || self.timer > 40 {
                        self.enter(Phase::Release, env);
                        continue;
                    }
                    // Hover until centred, then press down slowly.
                    let hover = if xy > 0.004 { 0.008 } else { -0.003 };
                    let want = [stack_site[0], stack_site[1], stack_site[2] + hover];
                    speed = 0.08;
                    break (add(&pinch, &sub(&want, &b1)), place_yaw, 1.0);
                }
                Phase::Release => {
                    if self.timer > 10 {
                        self.enter(Phase::Retreat, env);
                        continue;
                    }
                    // Open gently (to the pre-shape angle, at most 40% speed): a fast open flicks the brick.
                    break (self.anchor, self.anchor_yaw, preshape.max(-0.4));
                }
                Phase::Retreat => {
                    let t = [self.anchor[0], self.anchor[1], self.anchor[2] + 0.08];
                    break (t, self.anchor_yaw, preshape.max(-0.4));
                }
            }
        };
        let mut action = track(env, &target, yaw, speed);
        for a in &mut action[ARM_JOINTS..] {
            *a = fingers as f32;
        }
        action
    }
}

/// Resolved-rate step towards `target` with the hand pointing down at `yaw`, the pinch site at most
/// `max_speed` fast (fingers left at 0).
pub(crate) fn track(env: &JacoEnv, target: &[f64; 3], yaw: f64, max_speed: f64) -> [f32; ACT_DIM] {
    let ids = env.scene().ids();
    let e = pose_error(
        env.data(),
        ids,
        &Vector3::from(*target),
        &down_rotation(yaw),
    );
    let mut twist = Vector6::zeros();
    let lin = linear(&e).norm() * POSITION_GAIN;
    let s = if lin > max_speed {
        max_speed / lin
    } else {
        1.0
    };
    let ang = angular(&e).norm() * ORIENTATION_GAIN;
    let sr = if ang > MAX_ANGULAR_SPEED {
        MAX_ANGULAR_SPEED / ang
    } else {
        1.0
    };
    for i in 0..3 {
        twist[i] = e[i] * POSITION_GAIN * s;
        twist[3 + i] = e[3 + i] * ORIENTATION_GAIN * sr;
    }
    let jac = arm_jacobian(env.data(), ids);
    let qdot = damped_least_squares(&jac, &twist, 0.02);
    let mut action = [0.0f32; ACT_DIM];
    let mut worst = 1.0f64;
    for j in 0..ARM_JOINTS {
        let scale = f64::from(ACTION_JOINTS[j].scale);
        worst = worst.max((qdot[j] / scale).abs());
    }
    for j in 0..ARM_JOINTS {
        let scale = f64::from(ACTION_JOINTS[j].scale);
        action[j] = (qdot[j] / scale / worst) as f32;
    }
    action
}

/// Yaw of a frame's x axis.
pub(crate) fn yaw_of(m: &Rotation3<f64>) -> f64 {
    m[(1, 0)].atan2(m[(0, 0)])
}

/// Wraps an angle difference into (-pi/2, pi/2] (a brick looks the same turned by pi).
pub(crate) fn wrap_half_pi(a: f64) -> f64 {
    use std::f64::consts::PI;
    let mut a = a % PI;
    if a > PI / 2.0 {
        a -= PI;
    } else if a <= -PI / 2.0 {
        a += PI;
    }
    a
}

/// The angle equivalent to `a` modulo pi that is nearest to `reference`.
pub(crate) fn nearest_equivalent(a: f64, reference: f64) -> f64 {
    reference + wrap_half_pi(a - reference)
}

pub(crate) fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn add(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_helpers() {
        use std::f64::consts::PI;
        assert!((wrap_half_pi(PI) - 0.0).abs() < 1e-12);
        assert!((wrap_half_pi(0.75 * PI) + 0.25 * PI).abs() < 1e-12);
        assert!((nearest_equivalent(0.1, PI) - (PI + 0.1)).abs() < 1e-12);
    }
}
