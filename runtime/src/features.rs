//! Task features: values the controller derives from one observation with the arm's forward
//! kinematics, which a policy may take as extra inputs after the observation.
//!
//! A two-layer network cloned from the demonstrator has to compute the hand's yaw relative to a
//! brick, modulo the brick's half-turn symmetry, from six joint sines and cosines and a
//! quaternion; its failures spin the wrist without stopping at the brick's yaw (docs/imitation.md).
//! These features hand it those quantities: the pinch site's pose comes from
//! [`crate::kinematics::pinch_pose`] (the same bits on every target), sines and cosines from the
//! f32 [`crate::kinematics::sin_cos`] (`libm`'s `sinf`/`cosf` compute in f64, which the
//! Cortex-M4F runs in software: about 27,000 instructions per step), arc tangents from `libm`.
//!
//! A policy file takes them when its observation fields are the controller's
//! ([`crate::interface::OBSERVATION_FIELDS`]) followed by [`FEATURE_FIELDS`]; [`check_layout`]
//! accepts exactly those two layouts and [`policy_input`] fills the network's input for either.
//!
//! Yaws are those of a frame's x axis in the table plane (the pinch site's closing axis, a brick's
//! long axis); a relative yaw `d` between a frame and a brick enters as `sin 2d, cos 2d`, which a
//! brick turned by half a turn leaves unchanged.

use dex_policy::{FormatError, PolicyView};
use nalgebra::Vector3;

use crate::interface::{ACTION_JOINTS, OBS_DIM, OBSERVATION_FIELDS};
use crate::kinematics::{ARM_JOINTS, pinch_pose, sin_cos};

/// One named block of task features.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeatureField {
    /// Field name, as a policy file lists it after the observation fields.
    pub name: &'static str,
    /// Number of values.
    pub size: u16,
}

/// The task features, in order.
pub const FEATURE_FIELDS: &[FeatureField] = &[
    FeatureField {
        name: "pinch_yaw",
        size: 2,
    },
    FeatureField {
        name: "brick1_yaw_to_pinch",
        size: 2,
    },
    FeatureField {
        name: "brick2_yaw_to_pinch",
        size: 2,
    },
    FeatureField {
        name: "brick2_yaw_to_brick1",
        size: 2,
    },
    FeatureField {
        name: "pinch_to_brick1_local",
        size: 3,
    },
    FeatureField {
        name: "pinch_to_brick2_local",
        size: 3,
    },
];

/// Number of feature values.
pub const FEATURE_DIM: usize = 14;

const _: () = {
    let mut n = 0;
    let mut i = 0;
    while i < FEATURE_FIELDS.len() {
        n += FEATURE_FIELDS[i].size as usize;
        i += 1;
    }
    assert!(n == FEATURE_DIM);
};

/// Most inputs a Jaco policy takes: the observation and the task features.
pub const INPUT_MAX: usize = OBS_DIM + FEATURE_DIM;

/// Checks that `view` is a policy for this cell: the observation fields of
/// [`crate::interface`], alone or followed by [`FEATURE_FIELDS`], and its action joints.
pub fn check_layout(view: &PolicyView<'_>) -> Result<(), FormatError> {
    let observation = OBSERVATION_FIELDS.iter().map(|f| (f.name, f.size));
    let actions = ACTION_JOINTS.iter().map(|j| j.name);
    if view.body().obs_dim() == INPUT_MAX {
        let features = FEATURE_FIELDS.iter().map(|f| (f.name, usize::from(f.size)));
        view.check_layout(observation.chain(features), actions)
    } else {
        view.check_layout(observation, actions)
    }
}

/// Whether a policy whose file checked with [`check_layout`] takes `inputs` values takes the task
/// features.
pub const fn takes_features(inputs: usize) -> bool {
    inputs == INPUT_MAX
}

/// The network input of a policy that takes `inputs` values (checked with [`check_layout`]):
/// `obs` alone, or `obs` followed by its [`task_features`], written into `buf`.
pub fn policy_input<'b>(
    obs: &[f32; OBS_DIM],
    inputs: usize,
    buf: &'b mut [f32; INPUT_MAX],
) -> &'b [f32] {
    buf[..OBS_DIM].copy_from_slice(obs);
    if takes_features(inputs) {
        buf[OBS_DIM..].copy_from_slice(&task_features(obs));
        &buf[..]
    } else {
        &buf[..OBS_DIM]
    }
}

/// The observation layout of a policy that takes the task features, as its file lists it.
pub fn policy_observation_with_features()
-> heapless::Vec<dex_policy::ObsField<'static>, { dex_policy::MAX_OBS_FIELDS }> {
    let mut fields = crate::interface::policy_observation();
    for f in FEATURE_FIELDS {
        // 10 + 6 fields: within MAX_OBS_FIELDS (32).
        let _ = fields.push(dex_policy::ObsField {
            name: f.name,
            size: f.size,
        });
    }
    fields
}

// Offsets of the observation fields the features read (crate::interface::OBSERVATION_FIELDS).
const SIN: usize = 0;
const COS: usize = 6;
const BRICK1_QUAT: usize = 27;
const BRICK2_QUAT: usize = 34;
const PINCH_TO_BRICK1: usize = 38;
const PINCH_TO_BRICK2: usize = 41;

/// Yaw of a (w, x, y, z) quaternion's x axis in the table plane; its norm does not matter.
fn quat_yaw(q: &[f32]) -> f32 {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    libm::atan2f(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
}

/// `sin 2d, cos 2d` of the angle `d` from yaw `from` to yaw `to`.
fn half_turn_pair(to: f32, from: f32) -> [f32; 2] {
    let (s, c) = sin_cos(2.0 * (to - from));
    [s, c]
}

/// The task features of physical observation `obs` (units as [`crate::interface`] lists them),
/// in [`FEATURE_FIELDS`] order. Bounded work: one forward-kinematics pass and a few angles.
/// Finite for every finite observation.
pub fn task_features(obs: &[f32; OBS_DIM]) -> [f32; FEATURE_DIM] {
    let q: [f32; ARM_JOINTS] = core::array::from_fn(|j| libm::atan2f(obs[SIN + j], obs[COS + j]));
    let pose = pinch_pose(&q);
    let x = pose.rot * Vector3::x();
    let pinch_yaw = libm::atan2f(x[1], x[0]);
    let (pinch_sin, pinch_cos) = sin_cos(pinch_yaw);
    let yaw1 = quat_yaw(&obs[BRICK1_QUAT..BRICK1_QUAT + 4]);
    let yaw2 = quat_yaw(&obs[BRICK2_QUAT..BRICK2_QUAT + 4]);
    let local = |at: usize| -> [f32; 3] {
        let v = Vector3::new(obs[at], obs[at + 1], obs[at + 2]);
        // The inverse of a unit quaternion is its conjugate (no division).
        let l = pose.rot.conjugate() * v;
        [l[0], l[1], l[2]]
    };
    let [s1, c1] = half_turn_pair(yaw1, pinch_yaw);
    let [s2, c2] = half_turn_pair(yaw2, pinch_yaw);
    let [s21, c21] = half_turn_pair(yaw2, yaw1);
    let l1 = local(PINCH_TO_BRICK1);
    let l2 = local(PINCH_TO_BRICK2);
    [
        pinch_sin, pinch_cos, s1, c1, s2, c2, s21, c21, l1[0], l1[1], l1[2], l2[0], l2[1], l2[2],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An observation with arm angles `q`, brick 1 turned by `yaw1` about z and brick 2 by `yaw2`.
    fn obs(q: [f32; 6], yaw1: f32, yaw2: f32) -> [f32; OBS_DIM] {
        let mut o = [0.0f32; OBS_DIM];
        for j in 0..6 {
            o[SIN + j] = libm::sinf(q[j]);
            o[COS + j] = libm::cosf(q[j]);
        }
        let quat = |yaw: f32| [libm::cosf(yaw / 2.0), 0.0, 0.0, libm::sinf(yaw / 2.0)];
        o[BRICK1_QUAT..BRICK1_QUAT + 4].copy_from_slice(&quat(yaw1));
        o[BRICK2_QUAT..BRICK2_QUAT + 4].copy_from_slice(&quat(yaw2));
        o[PINCH_TO_BRICK1..PINCH_TO_BRICK1 + 3].copy_from_slice(&[0.1, -0.05, -0.2]);
        o[PINCH_TO_BRICK2..PINCH_TO_BRICK2 + 3].copy_from_slice(&[-0.1, 0.2, -0.25]);
        o
    }

    const Q: [f32; 6] = [-1.6, 3.0, 1.2, -2.0, 1.4, 0.3];

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-5
    }

    #[test]
    fn a_brick_turned_by_half_a_turn_gives_the_same_features() {
        let a = task_features(&obs(Q, 0.4, -1.0));
        let b = task_features(&obs(Q, 0.4 + core::f32::consts::PI, -1.0));
        for (x, y) in a.iter().zip(&b) {
            assert!(close(*x, *y), "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn the_wrist_turns_the_pinch_yaw_and_the_relative_yaws_with_it() {
        let a = task_features(&obs(Q, 0.4, -1.0));
        let mut q = Q;
        q[5] += 0.25;
        let b = task_features(&obs(q, 0.4, -1.0));
        let yaw = |f: &[f32; FEATURE_DIM]| libm::atan2f(f[0], f[1]);
        let turn = yaw(&b) - yaw(&a);
        // The last joint turns the hand about its own axis, which moves its closing axis's yaw.
        assert!(turn.abs() > 0.01, "turn {turn}");
        // The brick-to-pinch angle (doubled) moved by twice the hand's turn, the other way.
        let rel = |f: &[f32; FEATURE_DIM]| libm::atan2f(f[2], f[3]);
        let d = rel(&b) - rel(&a);
        let wrapped = libm::atan2f(libm::sinf(d + 2.0 * turn), libm::cosf(d + 2.0 * turn));
        assert!(wrapped.abs() < 1e-3, "d {d} turn {turn}");
        // The bricks' relative yaw does not depend on the arm.
        assert!(close(a[6], b[6]) && close(a[7], b[7]));
    }

    #[test]
    fn local_vectors_keep_their_length_and_the_pairs_are_unit() {
        let f = task_features(&obs(Q, 0.4, -1.0));
        let norm = |v: &[f32]| libm::sqrtf(v.iter().map(|x| x * x).sum::<f32>());
        assert!(close(norm(&f[8..11]), norm(&[0.1, -0.05, -0.2])));
        assert!(close(norm(&f[11..14]), norm(&[-0.1, 0.2, -0.25])));
        for pair in f[..8].chunks(2) {
            assert!(close(norm(pair), 1.0));
        }
        assert!(f.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn the_bricks_relative_yaw_is_the_difference_of_their_yaws() {
        let f = task_features(&obs(Q, 0.4, -0.5));
        assert!(close(f[6], libm::sinf(2.0 * -0.9)) && close(f[7], libm::cosf(2.0 * -0.9)));
    }
}
