//! A Markov scripted demonstrator: its action is a function of the current state alone.
//!
//! The phase-machine [`Demonstrator`](super::Demonstrator) keeps a phase, timers and anchors, so the
//! same observation can get different actions (hovering above the brick it may be about to descend
//! or still waiting for its wrist), which a memoryless policy cannot imitate, and its labels on
//! states off its own path describe a phase that no longer fits them. This one recomputes the phase
//! from the state at every step (brick held? on brick 2? pinch at the grasp point? fingers closed
//! and settled?) and blends where the phase machine switches (the hand descends as it aligns),
//! so it is an oracle at any state: cloning it is plain regression, and DAgger can ask it about
//! the learner's own states (`dex_trainer::pipeline::imitation`).
//!
//! Placing differs from the phase machine's: brick 1 comes down in proportion to how well it is
//! centred over brick 2 and turned to brick 2's yaw (modulo the half turn) rather than after a
//! threshold, so the label stays a continuous function of the state where it can (with the
//! thresholded placing a cloned Stack policy hovered over brick 2 in 23 of 32 failures,
//! docs/imitation.md). Session 5 did not turn brick 1 at all; a misaligned brick rests on brick 2's
//! studs and, held near its edge as the StackInHand starts hold it, pivots off them when the fingers
//! open (most of its StackInHand failures).
//!
//! Grasping (issue #26): the fingers approach at [`APPROACH_FINGERS`] (0.8 rad), not the phase
//! machine's 0.5: from 0.5 a closing finger swings down before it swings in and caught on the table
//! in most Grasp failures. "Closed" is then [`CLOSED`] = 0.95. A finger whose knuckle is near brick
//! 2 approaches tucked ([`TUCKED`], [`TUCK_GAP`]) so it does not come down on brick 2, and where
//! the two grasp sides are about equally far for the wrist the hand takes the one that keeps its
//! knuckles off brick 2 ([`FLIP_GAP`], [`FLIP_TURN`]). Released over brick 2, brick 1 keeps being
//! released while it stays within [`RELEASE_XY`] of the stacking site.
//!
//! Thresholds are radians for fingers, metres and m/s, measured on the phase machine's episodes: a
//! gripped brick holds the fingers at a mean 1.0-1.2 rad, settling fingers creep below 0.25 rad/s.

use dex_runtime::interface::ACT_DIM;

use super::EnvError;
use super::demo::{
    APPROACH_HEIGHT, CARRY_CLEARANCE, LIFT_HEIGHT, MAX_SPEED, PRESHAPE, add, nearest_equivalent,
    sub, track, wrap_half_pi, yaw_of,
};
use super::environment::JacoEnv;
use super::kinematics::{pinch_pose, xmat_rotation};
use super::scene::{ARM_JOINTS, BRICK_HALF_EXTENTS, BRICK_HEIGHT, FINGER_JOINTS, GRASP_DEPTH};
use super::start_states::Demonstration;
use super::tasks::Task;
use mujoco_rs::prelude::MjtObjBase;
use nalgebra::{Vector2, Vector3};
use std::f64::consts::PI;

/// The finger (proximal phalanx) bodies, whose origins are the knuckles.
pub(crate) const KNUCKLES: [&str; FINGER_JOINTS] =
    ["hand/b_finger_1", "hand/b_finger_2", "hand/b_finger_3"];
/// The fingertip bodies.
pub(crate) const TIPS: [&str; FINGER_JOINTS] = [
    "hand/b_finger_tip_1",
    "hand/b_finger_tip_2",
    "hand/b_finger_tip_3",
];

/// Horizontal distance from `p` to the footprint of a brick at `origin` with orientation `m`
/// (row-major), 0 inside it.
fn footprint_gap(p: &[f64; 3], origin: &[f64; 3], m: &[f64; 9]) -> f64 {
    let d = [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]];
    // Along the brick's x and y axes (columns of m).
    let x = m[0] * d[0] + m[3] * d[1] + m[6] * d[2];
    let y = m[1] * d[0] + m[4] * d[1] + m[7] * d[2];
    let gx = (x.abs() - BRICK_HALF_EXTENTS[0]).max(0.0);
    let gy = (y.abs() - BRICK_HALF_EXTENTS[1]).max(0.0);
    gx.hypot(gy)
}

/// Mean finger angle above which the hand counts as closed (gripping holds 1.0-1.2; the fingers
/// approach at [`APPROACH_FINGERS`], so "closed" must lie clearly above that).
pub const CLOSED: f64 = 0.95;
/// Finger angle (rad) the fingers hold while approaching the brick. At 0.8 the fingertips hang at
/// the low point of their arc, beside the brick and about 2.5 cm off its sides: closing from there
/// moves them inwards, whereas from the phase machine's 0.5 they swing down first and a finger can
/// catch on the table (the failures of the first version: one finger stuck near 0.4 while the others
/// closed).
pub const APPROACH_FINGERS: f64 = 0.8;
/// Finger angle (rad) of a tucked finger while approaching: its tip about 1 cm further in than at
/// [`APPROACH_FINGERS`].
pub const TUCKED: f64 = 0.95;
/// A finger is tucked ([`TUCKED`]) while its knuckle is within this horizontal distance (m) of brick
/// 2's footprint: at [`APPROACH_FINGERS`] its tip would reach over brick 2 and, coming down, rest on
/// it and hold the hand above the grasp point (most of the remaining Grasp failures, brick 2 about
/// 8 cm away). The knuckle is fixed in the hand, so the choice does not flip as the finger moves.
pub const TUCK_GAP: f64 = 0.03;
/// With [`MarkovDemonstrator::with_tuck_first`]: a finger that should be tucked holds the hand at
/// the approach height while its angle is at most this (rad) ...
pub const TUCK_HOLD_FROM: f64 = TUCKED - 0.15;
/// ... and lets it descend freely from this angle on (a linear ramp between the two, so the label
/// is a continuous function of the finger's angle).
pub const TUCK_HOLD_TO: f64 = TUCKED - 0.05;
/// The hold applies only to a finger whose tip is within this horizontal distance (m) of brick 2's
/// footprint: the tip that would come down on brick 2 (or rests on it).
pub const TUCK_HOLD_TIP_GAP: f64 = 0.015;
/// The hand grasps brick 1 from the other side (the half turn from the brick's yaw nearest its own)
/// when, at the grasp point, a knuckle would come within this distance (m) of brick 2's footprint and
/// the other side keeps the knuckles further away. A function of the state (brick poses, hand yaw):
/// past the quarter turn the other side is the nearest and stays chosen.
pub const FLIP_GAP: f64 = 0.01;
/// With [`MarkovDemonstrator::with_tuck_ramp`]: a finger is fully tucked while its knuckle is
/// within this horizontal distance (m) of brick 2's footprint ...
pub const TUCK_RAMP_NEAR: f64 = TUCK_GAP - 0.01;
/// ... and not tucked at all from this distance on (linear between; centred on [`TUCK_GAP`]).
pub const TUCK_RAMP_FAR: f64 = TUCK_GAP + 0.01;
/// The [`FLIP_GAP`] flip applies only where the other side is at most this hand turn (rad) away, i.e.
/// where the two sides are nearly as far (a longer turn costs more of the episode than it saves).
pub const FLIP_TURN: f64 = 2.6;
/// Brick 1 counts as set down on brick 2 for release within this horizontal offset (m) of the stacking
/// site (and [`PLACE_DZ`] vertically): once the fingers start opening the brick may shift a little,
/// and the release must go on rather than squeeze again.
pub const RELEASE_XY: f64 = 0.006;
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
/// Brick 1 low enough over the stacking site for release (vertical, with [`RELEASE_XY`]).
pub const PLACE_DZ: f64 = 0.007;
/// Horizontal offset of brick 1 from the stacking site within which it is lowered all the way.
pub const PLACE_CENTRED: f64 = 0.003;
/// Offset span (beyond [`PLACE_CENTRED`]) over which the lowering blends back to the carry height.
pub const PLACE_BLEND: f64 = 0.007;
/// Yaw error (rad) between held brick 1 and brick 2 within which brick 1 is lowered all the way: an
/// aligned brick seats between brick 2's studs, a misaligned one rests on them and pivots off when
/// the fingers open.
pub const PLACE_ALIGNED: f64 = 0.05;
/// Yaw error span (beyond [`PLACE_ALIGNED`]) over which the lowering blends back to the carry height.
pub const PLACE_ALIGN_BLEND: f64 = 0.1;
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
    tuck_first: bool,
    tuck_ramp: bool,
}

impl MarkovDemonstrator {
    /// The demonstrator for `task` (Reach: approach only).
    pub const fn new(task: Task) -> Self {
        Self {
            task,
            tuck_first: false,
            tuck_ramp: false,
        }
    }

    /// Tuck first: while approaching, a finger that should be tucked and is not yet
    /// ([`tuck_hold`]) holds the hand up, so it descends only with its fingers tucked. Without it
    /// a finger whose tip came to rest on brick 2 cannot tuck (the tip is pressed on the brick)
    /// and the hand, held about 1 cm above the grasp point, never reaches it: the state in which
    /// 20 of the Grasp clone's 26 failures in 2000 starts stalled, and from which this
    /// demonstrator without the switch recovered in 9 of 20 (docs/experiments.md, session 21).
    pub const fn with_tuck_first(self, on: bool) -> Self {
        Self {
            tuck_first: on,
            ..self
        }
    }

    /// Whether [`MarkovDemonstrator::with_tuck_first`] is on.
    pub const fn tuck_first(&self) -> bool {
        self.tuck_first
    }

    /// Tuck ramp: a finger's approach angle goes from [`APPROACH_FINGERS`] to [`TUCKED`] linearly
    /// as its knuckle's gap to brick 2's footprint falls from [`TUCK_RAMP_FAR`] to
    /// [`TUCK_RAMP_NEAR`] ([`tuck_weight`]), where without it the angle switches at [`TUCK_GAP`].
    /// The label is then a continuous function of the state, which a network can fit; at the
    /// switch it jumps by 0.6 (normalised), and the clone, averaging the two sides, tucks too
    /// little (docs/experiments.md, session 22).
    pub const fn with_tuck_ramp(self, on: bool) -> Self {
        Self {
            tuck_ramp: on,
            ..self
        }
    }

    /// Whether [`MarkovDemonstrator::with_tuck_ramp`] is on.
    pub const fn tuck_ramp(&self) -> bool {
        self.tuck_ramp
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
        // Per finger: approach at APPROACH_FINGERS, or TUCKED next to brick 2.
        let model = env.scene().model();
        let knuckles: [Option<[f64; 3]>; FINGER_JOINTS] = core::array::from_fn(|k| {
            model
                .name_to_id(MjtObjBase::mjOBJ_BODY, KNUCKLES[k])
                .map(body)
        });
        let finger_q = |k: usize| {
            finger_joints
                .get(k)
                .and_then(|&a| data.qpos().get(a).copied())
                .unwrap_or(0.0)
        };
        let knuckle_gaps: [Option<f64>; FINGER_JOINTS] =
            core::array::from_fn(|k| knuckles[k].map(|p| footprint_gap(&p, &b2, &m2)));
        let near_brick2: [bool; FINGER_JOINTS] =
            core::array::from_fn(|k| knuckle_gaps[k].is_some_and(|g| g < TUCK_GAP));
        let tip_over_brick2 = |k: usize| {
            model
                .name_to_id(MjtObjBase::mjOBJ_BODY, TIPS[k])
                .map(body)
                .is_some_and(|p| footprint_gap(&p, &b2, &m2) < TUCK_HOLD_TIP_GAP)
        };
        let approach_fingers: [f64; FINGER_JOINTS] = core::array::from_fn(|k| {
            let q = finger_q(k);
            let want = if self.tuck_ramp {
                let w = knuckle_gaps[k].map_or(0.0, tuck_weight);
                APPROACH_FINGERS + (TUCKED - APPROACH_FINGERS) * w
            } else if near_brick2[k] {
                TUCKED
            } else {
                APPROACH_FINGERS
            };
            ((want - q) * 4.0).clamp(-1.0, 1.0)
        });
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
        let set_down = site_xy < RELEASE_XY && b1[2] - site[2] < PLACE_DZ;
        let stacking = matches!(self.task, Task::Stack | Task::StackInHand);

        let grasp_point = [b1[0], b1[1], b1[2] + GRASP_DEPTH];
        let to_grasp = sub(&grasp_point, &pinch);
        // The grasp yaw: the brick's yaw nearest the hand's, or the half turn from it if a knuckle
        // would come within FLIP_GAP of brick 2 and the other side keeps the knuckles further away.
        let knuckle_gap = |yaw: f64| {
            let (s, c) = (yaw - hand_yaw).sin_cos();
            knuckles
                .iter()
                .flatten()
                .map(|k| {
                    let (dx, dy) = (k[0] - pinch[0], k[1] - pinch[1]);
                    let at = [
                        grasp_point[0] + c * dx - s * dy,
                        grasp_point[1] + s * dx + c * dy,
                        k[2],
                    ];
                    footprint_gap(&at, &b2, &m2)
                })
                .fold(f64::INFINITY, f64::min)
        };
        let near = nearest_equivalent(yaw_of(&xmat_rotation(&m1)), hand_yaw);
        let far = if near >= hand_yaw {
            near - PI
        } else {
            near + PI
        };
        let grasp_yaw = if (far - hand_yaw).abs() < FLIP_TURN
            && knuckle_gap(near) < FLIP_GAP
            && knuckle_gap(far) > knuckle_gap(near)
        {
            far
        } else {
            near
        };
        let up_from_here = |z: f64| [pinch[0], pinch[1], z];
        // Hand turn that aligns held brick 1 with brick 2 (modulo the bricks' half-turn symmetry).
        let place_turn = wrap_half_pi(yaw_of(&xmat_rotation(&m2)) - yaw_of(&xmat_rotation(&m1)));

        let (phase, target, yaw, speed, finger_cmd) = if stacking && on_stack && f_mean < OPENED {
            (
                MarkovPhase::Retreat,
                up_from_here(site[2] + 0.1),
                hand_yaw,
                MAX_SPEED,
                [gentle_open; FINGER_JOINTS],
            )
        } else if stacking && in_hand && f_mean >= OPENED && set_down {
            (
                MarkovPhase::Release,
                pinch,
                hand_yaw,
                MAX_SPEED,
                [gentle_open; FINGER_JOINTS],
            )
        } else if held && self.task == Task::Grasp {
            (
                MarkovPhase::Hold,
                up_from_here(LIFT_HEIGHT),
                hand_yaw,
                MAX_SPEED,
                [1.0; FINGER_JOINTS],
            )
        } else if held && stacking {
            if b1[2] < CARRY_FROM && site_xy > 0.01 {
                (
                    MarkovPhase::Lift,
                    up_from_here(pinch[2] + 0.05),
                    hand_yaw,
                    MAX_SPEED,
                    [1.0; FINGER_JOINTS],
                )
            } else {
                // Carry to above the stacking site, coming down as brick 1 centres over it and turns
                // to brick 2's yaw: fully lowered within PLACE_CENTRED and PLACE_ALIGNED, at the
                // carry height from PLACE_CENTRED + PLACE_BLEND (PLACE_ALIGNED + PLACE_ALIGN_BLEND)
                // off, so the label is a continuous function of the offset and the yaw error.
                let w = ((site_xy - PLACE_CENTRED) / PLACE_BLEND)
                    .max((place_turn.abs() - PLACE_ALIGNED) / PLACE_ALIGN_BLEND)
                    .clamp(0.0, 1.0);
                let height = -0.003 + (CARRY_CLEARANCE + 0.003) * w;
                let want = [site[0], site[1], site[2] + height];
                let (phase, speed) = if w < 1.0 {
                    (MarkovPhase::Lower, LOWER_SPEED)
                } else {
                    (MarkovPhase::Carry, MAX_SPEED)
                };
                (
                    phase,
                    add(&pinch, &sub(&want, &b1)),
                    hand_yaw + place_turn,
                    speed,
                    [1.0; FINGER_JOINTS],
                )
            }
        } else if self.task != Task::Reach
            && Vector3::from(to_grasp).norm() < AT_GRASP
            && f_mean > APPROACH_FINGERS - 0.1
        {
            // At the grasp point: close, and lift once the fingers have settled on the brick.
            if closed && finger_speed < SETTLED {
                (
                    MarkovPhase::Lift,
                    up_from_here(LIFT_HEIGHT),
                    hand_yaw,
                    MAX_SPEED,
                    [1.0; FINGER_JOINTS],
                )
            } else {
                (
                    MarkovPhase::Close,
                    grasp_point,
                    hand_yaw,
                    MAX_SPEED,
                    [1.0; FINGER_JOINTS],
                )
            }
        } else {
            // Approach: above the brick at the approach height, coming down as the hand aligns.
            let xy = Vector2::new(to_grasp[0], to_grasp[1]).norm();
            let yaw_err = (grasp_yaw - hand_yaw).abs();
            let w = (2.0 * (xy / DESCEND_XY).max(yaw_err / DESCEND_YAW) - 1.0).clamp(0.0, 1.0);
            let w = if self.tuck_first {
                (0..FINGER_JOINTS)
                    .filter(|&k| near_brick2[k] && tip_over_brick2(k))
                    .map(|k| tuck_hold(finger_q(k)))
                    .fold(w, f64::max)
            } else {
                w
            };
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
                approach_fingers,
            )
        };
        let mut action = track(env, &target, yaw, speed);
        for (a, c) in action[ARM_JOINTS..].iter_mut().zip(finger_cmd) {
            *a = c as f32;
        }
        (phase, action)
    }
}

/// How much a finger whose knuckle is `gap` (m) from brick 2's footprint is tucked
/// ([`MarkovDemonstrator::with_tuck_ramp`]): 1 up to [`TUCK_RAMP_NEAR`], 0 from [`TUCK_RAMP_FAR`],
/// linear between.
pub fn tuck_weight(gap: f64) -> f64 {
    ((TUCK_RAMP_FAR - gap) / (TUCK_RAMP_FAR - TUCK_RAMP_NEAR)).clamp(0.0, 1.0)
}

/// How far up (0: free to descend, 1: at the approach height) a finger that should be tucked and
/// stands at angle `q` holds the hand ([`MarkovDemonstrator::with_tuck_first`]): 1 up to
/// [`TUCK_HOLD_FROM`], 0 from [`TUCK_HOLD_TO`], linear between.
pub fn tuck_hold(q: f64) -> f64 {
    ((TUCK_HOLD_TO - q) / (TUCK_HOLD_TO - TUCK_HOLD_FROM)).clamp(0.0, 1.0)
}

impl Demonstration for MarkovDemonstrator {
    /// Stateless: nothing to restart.
    fn restart(&mut self) {}

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        Ok(MarkovDemonstrator::act(self, env))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tuck_hold_is_a_ramp_over_the_finger_angle() {
        assert_eq!(tuck_hold(0.0), 1.0);
        assert_eq!(tuck_hold(TUCK_HOLD_FROM), 1.0);
        assert_eq!(tuck_hold(TUCK_HOLD_TO), 0.0);
        assert_eq!(tuck_hold(TUCKED), 0.0);
        let mid = tuck_hold(0.5 * (TUCK_HOLD_FROM + TUCK_HOLD_TO));
        assert!((mid - 0.5).abs() < 1e-9, "{mid}");
        // Non-increasing in the angle: a finger closer to tucked never holds the hand higher.
        let mut last = f64::INFINITY;
        for i in 0..=100 {
            let h = tuck_hold(0.7 + 0.003 * f64::from(i));
            assert!(h <= last);
            last = h;
        }
        assert!(!MarkovDemonstrator::new(Task::Grasp).tuck_first());
    }

    #[test]
    fn the_tuck_ramp_falls_over_the_knuckle_gap_through_the_switch() {
        assert_eq!(tuck_weight(0.0), 1.0);
        assert_eq!(tuck_weight(TUCK_RAMP_NEAR), 1.0);
        assert_eq!(tuck_weight(TUCK_RAMP_FAR), 0.0);
        assert_eq!(tuck_weight(1.0), 0.0);
        // Half tucked where the switch it replaces flips.
        assert!((tuck_weight(TUCK_GAP) - 0.5).abs() < 1e-9);
        // Continuous: no step larger than the slope allows.
        let mut last = tuck_weight(0.0);
        for i in 1..=600 {
            let w = tuck_weight(1e-4 * f64::from(i));
            assert!(w <= last && last - w <= 1e-4 / (TUCK_RAMP_FAR - TUCK_RAMP_NEAR) + 1e-12);
            last = w;
        }
        let d = MarkovDemonstrator::new(Task::Grasp);
        assert!(!d.tuck_ramp() && d.with_tuck_ramp(true).tuck_ramp());
        assert!(!d.with_tuck_ramp(true).tuck_first());
    }
}
