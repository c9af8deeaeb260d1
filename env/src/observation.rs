//! The observation vector, built in exactly the order and sizes of
//! [`dex_runtime::interface::OBSERVATION_FIELDS`].

use std::sync::Arc;

use dex_runtime::interface::{OBS_DIM, OBSERVATION_FIELDS};
use mujoco_rs::prelude::*;

#[cfg(test)]
use super::scene::FINGER_JOINTS;
use super::scene::{ARM_JOINTS, SceneIds};

/// One observation: 44 `f32` values laid out as `OBSERVATION_FIELDS` says.
pub type Observation = [f32; OBS_DIM];

/// Sizes of the blocks this module writes, in order; checked against the interface in a test.
#[cfg(test)]
const WRITTEN_FIELDS: [(&str, usize); 10] = [
    ("arm_joint_sin", ARM_JOINTS),
    ("arm_joint_cos", ARM_JOINTS),
    ("finger_joint_pos", FINGER_JOINTS),
    ("joint_vel", ARM_JOINTS + FINGER_JOINTS),
    ("brick1_pos", 3),
    ("brick1_quat", 4),
    ("brick2_pos", 3),
    ("brick2_quat", 4),
    ("pinch_to_brick1", 3),
    ("pinch_to_brick2", 3),
];

/// Writes the observation of `data` (kinematics must be current) into `out`.
///
/// Brick positions are the brick body origins (centre of the bottom face) in the table frame; quaternions
/// are MuJoCo's (w, x, y, z); the pinch-to-brick vectors are brick origin minus pinch site.
pub fn write_observation(data: &MjData<Arc<MjModel>>, ids: &SceneIds, out: &mut Observation) {
    let qpos = data.qpos();
    let qvel = data.qvel();
    let q = |adr: usize| qpos.get(adr).copied().unwrap_or(0.0);
    let v = |adr: usize| qvel.get(adr).copied().unwrap_or(0.0);
    let mut w = Writer { out, at: 0 };
    for &adr in &ids.joint_qpos[..ARM_JOINTS] {
        w.push(q(adr).sin());
    }
    for &adr in &ids.joint_qpos[..ARM_JOINTS] {
        w.push(q(adr).cos());
    }
    for &adr in &ids.joint_qpos[ARM_JOINTS..] {
        w.push(q(adr));
    }
    for &adr in &ids.joint_dof {
        w.push(v(adr));
    }
    let xpos = data.xpos();
    let xquat = data.xquat();
    let b1 = xpos.get(ids.brick1_body).copied().unwrap_or([0.0; 3]);
    let b2 = xpos.get(ids.brick2_body).copied().unwrap_or([0.0; 3]);
    let q1 = xquat
        .get(ids.brick1_body)
        .copied()
        .unwrap_or([1.0, 0.0, 0.0, 0.0]);
    let q2 = xquat
        .get(ids.brick2_body)
        .copied()
        .unwrap_or([1.0, 0.0, 0.0, 0.0]);
    let pinch = data
        .site_xpos()
        .get(ids.pinch_site)
        .copied()
        .unwrap_or([0.0; 3]);
    w.extend(&b1);
    w.extend(&q1);
    w.extend(&b2);
    w.extend(&q2);
    w.extend(&[b1[0] - pinch[0], b1[1] - pinch[1], b1[2] - pinch[2]]);
    w.extend(&[b2[0] - pinch[0], b2[1] - pinch[1], b2[2] - pinch[2]]);
    debug_assert_eq!(w.at, OBS_DIM);
}

struct Writer<'a> {
    out: &'a mut Observation,
    at: usize,
}

impl Writer<'_> {
    fn push(&mut self, x: f64) {
        if let Some(slot) = self.out.get_mut(self.at) {
            *slot = x as f32;
        }
        self.at += 1;
    }

    fn extend(&mut self, xs: &[f64]) {
        for &x in xs {
            self.push(x);
        }
    }
}

/// Offset of the named field in the observation vector, from the interface definition.
pub fn field_offset(name: &str) -> Option<usize> {
    let mut start = 0;
    for f in OBSERVATION_FIELDS {
        if f.name == name {
            return Some(start);
        }
        start += f.size;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_matches_the_interface() {
        assert_eq!(OBSERVATION_FIELDS.len(), WRITTEN_FIELDS.len());
        for (f, (name, size)) in OBSERVATION_FIELDS.iter().zip(WRITTEN_FIELDS) {
            assert_eq!((f.name, f.size), (name, size));
        }
        assert_eq!(WRITTEN_FIELDS.iter().map(|f| f.1).sum::<usize>(), OBS_DIM);
        assert_eq!(OBS_DIM, 44);
        assert_eq!(field_offset("brick1_pos"), Some(24));
        assert_eq!(field_offset("pinch_to_brick2"), Some(41));
    }
}
