//! A Markov scripted demonstrator: its action is a function of the current state alone.
//!
//! The phase-machine [`Demonstrator`](super::Demonstrator) keeps a phase, timers and anchors, so the
//! same observation can get different actions (hovering above the brick it may be about to descend
//! or still waiting for its wrist), which a memoryless policy cannot imitate, and its labels on
//! states off its own path describe a phase that no longer fits them. This one recomputes the phase
//! from the state at every step (brick held? on brick 2? pinch at the grasp point? fingers closed
//! and settled?) and blends where the phase machine switches (the hand descends as it aligns),
//! so it is an oracle at any state: cloning it is plain regression, and DAgger can ask it about
//! the learner's own states (`dex_trainer::imitation`).
//!
//! Placing differs from the phase machine's on purpose: brick 1 is not turned to brick 2's yaw (the
//! stack predicate is an offset of origins and a misaligned brick rests on the studs inside it),
//! and it comes down in proportion to how well it is centred rather than after a threshold. Both
//! make the label a smooth function of the state: with the yaw-aligned, thresholded placing a
//! cloned Stack policy hovered over brick 2 in 23 of 32 failures (docs/imitation.md); without it
//! the demonstrator still stacks 96% (192/200, against 98.5%) and its clones do better.
//!
//! Thresholds are radians for fingers, metres and m/s, measured on the phase machine's episodes: a
//! gripped brick holds the fingers at a mean 1.0-1.2 rad, the pre-shape is 0.5, settling fingers
//! creep below 0.25 rad/s.

use dex_runtime::interface::ACT_DIM;

use super::EnvError;
use super::demo::{
    APPROACH_HEIGHT, CARRY_CLEARANCE, LIFT_HEIGHT, MAX_SPEED, PRESHAPE, add, nearest_equivalent,
    sub, track, yaw_of,
};
use super::environment::{GRASP_DEPTH, JacoEnv};
use super::kinematics::{pinch_pose, xmat_rotation};
use super::scene::{ARM_JOINTS, BRICK_HEIGHT};
use super::start_states::Demonstration;
use super::tasks::Task;
use nalgebra::{Vector2, Vector3};

/// Mean finger angle above which the hand counts as closed (gripping holds 1.0-1.2).
pub const CLOSED: f64 = 0.8;
/// Mean finger angle below which released fingers are open enough to move away.
pub const OPENED: f64 = 0.55;
/// Finger speed below which closing fingers have settled on the brick.
pub const SETTLED: f64 = 0.25;
/// Brick 1 counts as in the hand within this distance of the pinch site.
pub const IN_HAND: f64 = 0.04;
/// Brick 1 counts as lifted off the table above this height.
pub const LIFTED: f64 = 0.004;
/// The pinch site is at the grasp point within this distance.
pub const AT_GRASP: f64 = 0.008;
/// Horizontal distance and yaw error (m, rad) from which the hand stays at the approach height; it
/// descends linearly as both errors shrink to half of these.
pub const DESCEND_XY: f64 = 0.015;
/// See [`DESCEND_XY`].
pub const DESCEND_YAW: f64 = 0.08;
/// Brick 1 centred on the stacking site for release (horizontal, vertical).
pub const PLACE_XY: f64 = 0.003;
/// See [`PLACE_XY`].
pub const PLACE_DZ: f64 = 0.007;
/// Horizontal offset of brick 1 from the stacking site within which it is lowered all the way.
pub const PLACE_CENTRED: f64 = 0.003;
/// Offset span (beyond [`PLACE_CENTRED`]) over which the lowering blends back to the carry height.
pub const PLACE_BLEND: f64 = 0.007;
/// Brick 1 height from which a held brick is carried rather than lifted straight up.
pub const CARRY_FROM: f64 = 0.035;
/// Speed of the pinch site while lowering onto brick 2.
pub const LOWER_SPEED: f64 = 0.08;

/// What the Markov demonstrator does in a state (for tests and diagnostics).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MarkovPhase {
    /// Towards the grasp point, descending as the hand aligns; fingers pre-shaped.
    Approach,
    /// At the grasp point: close the fingers.
    Close,
    /// Fingers settled on the brick (or the brick held below the carry height): lift.
    Lift,
    /// Holding the brick up (Grasp).
    Hold,
    /// Held brick towards the point above brick 2.
    Carry,
    /// Held brick centred above brick 2: lower it.
    Lower,
    /// Brick 1 on brick 2: open the fingers gently.
    Release,
    /// Fingers open over the stacked brick: move up.
    Retreat,
}

/// The Markov demonstrator of a task (stateless: [`MarkovDemonstrator::act`] takes `&self`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MarkovDemonstrator {
    task: Task,
}

impl MarkovDemonstrator {
    /// The demonstrator for `task` (Reach: approach only).
    pub const fn new(task: Task) -> Self {
        Self { task }
    }

    /// The phase it is in at the environment's state.
    pub fn phase(&self, env: &JacoEnv) -> MarkovPhase {
        self.decide(env).0
    }

    /// The normalised action for the environment's current state.
    pub fn act(&self, env: &JacoEnv) -> [f32; ACT_DIM] {
        self.decide(env).1
    }

    fn decide(&self, env: &JacoEnv) -> (MarkovPhase, [f32; ACT_DIM]) {
        let ids = env.scene().ids();
        let data = env.data();
        let body = |b: usize| data.xpos().get(b).copied().unwrap_or([0.0; 3]);
        let mat = |b: usize| data.xmat().get(b).copied().unwrap_or([0.0; 9]);
        let (pinch, pinch_rot) = pinch_pose(data, ids);
        let pinch: [f64; 3] = pinch.into();
        let hand_yaw = yaw_of(&pinch_rot);
        let (b1, b2) = (body(ids.brick1_body), body(ids.brick2_body));
        let (m1, m2) = (mat(ids.brick1_body), mat(ids.brick2_body));
        let finger_joints = &ids.joint_qpos[ARM_JOINTS..];
        let f_mean = finger_joints
            .iter()
            .map(|&a| data.qpos().get(a).copied().unwrap_or(0.0))
            .sum::<f64>()
            / finger_joints.len().max(1) as f64;
        let finger_speed = ids.joint_dof[ARM_JOINTS..]
            .iter()
            .map(|&a| data.qvel().get(a).copied().unwrap_or(0.0).abs())
            .fold(0.0, f64::max);
        let preshape = ((PRESHAPE - f_mean) * 4.0).clamp(-1.0, 1.0);
        let gentle_open = preshape.max(-0.4);
        let closed = f_mean > CLOSED;
        let in_hand = Vector3::from(sub(&b1, &pinch)).norm() < IN_HAND;
        let held = in_hand && closed && b1[2] > LIFTED;
        let site = [
            b2[0] + m2[2] * BRICK_HEIGHT,
            b2[1] + m2[5] * BRICK_HEIGHT,
            b2[2] + m2[8] * BRICK_HEIGHT,
        ];
        let on_stack = env.reward_state().predicates().stack;
        let site_xy = Vector2::new(site[0] - b1[0], site[1] - b1[1]).norm();
        let placed = site_xy < PLACE_XY && b1[2] - site[2] < PLACE_DZ;
        let stacking = matches!(self.task, Task::Stack | Task::StackInHand);

        let grasp_point = [b1[0], b1[1], b1[2] + GRASP_DEPTH];
        let to_grasp = sub(&grasp_point, &pinch);
        let grasp_yaw = nearest_equivalent(yaw_of(&xmat_rotation(&m1)), hand_yaw);
        let up_from_here = |z: f64| [pinch[0], pinch[1], z];

        let (phase, target, yaw, speed, finger_cmd) = if stacking && on_stack && f_mean < OPENED {
            (
                MarkovPhase::Retreat,
                up_from_here(site[2] + 0.1),
                hand_yaw,
                MAX_SPEED,
                gentle_open,
            )
        } else if stacking && in_hand && f_mean >= OPENED && (placed || (on_stack && !closed)) {
            (
                MarkovPhase::Release,
                pinch,
                hand_yaw,
                MAX_SPEED,
                gentle_open,
            )
        } else if held && self.task == Task::Grasp {
            (
                MarkovPhase::Hold,
                up_from_here(LIFT_HEIGHT),
                hand_yaw,
                MAX_SPEED,
                1.0,
            )
        } else if held && stacking {
            if b1[2] < CARRY_FROM && site_xy > 0.01 {
                (
                    MarkovPhase::Lift,
                    up_from_here(pinch[2] + 0.05),
                    hand_yaw,
                    MAX_SPEED,
                    1.0,
                )
            } else {
                // Carry to above the stacking site, coming down as brick 1 centres over it: fully
                // lowered within PLACE_CENTRED, at the carry height from PLACE_CENTRED +
                // PLACE_BLEND off. The hand keeps its yaw (the stack predicate and the studs do not
                // need the bricks aligned), so the label is a smooth function of the offset.
                let w = ((site_xy - PLACE_CENTRED) / PLACE_BLEND).clamp(0.0, 1.0);
                let height = -0.003 + (CARRY_CLEARANCE + 0.003) * w;
                let want = [site[0], site[1], site[2] + height];
                let (phase, speed) = if w < 1.0 {
                    (MarkovPhase::Lower, LOWER_SPEED)
                } else {
                    (MarkovPhase::Carry, MAX_SPEED)
                };
                (phase, add(&pinch, &sub(&want, &b1)), hand_yaw, speed, 1.0)
            }
        } else if self.task != Task::Reach
            && Vector3::from(to_grasp).norm() < AT_GRASP
            && f_mean > PRESHAPE - 0.1
        {
            // At the grasp point: close, and lift once the fingers have settled on the brick.
            if closed && finger_speed < SETTLED {
                (
                    MarkovPhase::Lift,
                    up_from_here(LIFT_HEIGHT),
                    hand_yaw,
                    MAX_SPEED,
                    1.0,
                )
            } else {
                (MarkovPhase::Close, grasp_point, hand_yaw, MAX_SPEED, 1.0)
            }
        } else {
            // Approach: above the brick at the approach height, coming down as the hand aligns.
            let xy = Vector2::new(to_grasp[0], to_grasp[1]).norm();
            let yaw_err = (grasp_yaw - hand_yaw).abs();
            let w = (2.0 * (xy / DESCEND_XY).max(yaw_err / DESCEND_YAW) - 1.0).clamp(0.0, 1.0);
            let w = if self.task == Task::Reach { 0.0 } else { w };
            let target = [
                grasp_point[0],
                grasp_point[1],
                grasp_point[2] + APPROACH_HEIGHT * w,
            ];
            (
                MarkovPhase::Approach,
                target,
                grasp_yaw,
                MAX_SPEED,
                preshape,
            )
        };
        let mut action = track(env, &target, yaw, speed);
        for a in &mut action[ARM_JOINTS..] {
            *a = finger_cmd as f32;
        }
        (phase, action)
    }
}

impl Demonstration for MarkovDemonstrator {
    /// Stateless: nothing to restart.
    fn restart(&mut self) {}

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        Ok(MarkovDemonstrator::act(self, env))
    }
}
