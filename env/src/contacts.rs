//! What the robot touches, or nearly: its contacts with brick 2, and how close its fingertips come.
//!
//! On Stack the shipped clone fails about half the episodes in which a fingertip comes down on
//! brick 2 before the hand has grasped brick 1, and few of the others (docs/experiments.md,
//! session 40): the contact is the measurable precursor of most of its failures, and a fine-tune
//! can be charged for it (`trainer pg --contact-cost`).

use mujoco_rs::prelude::{MjModel, MjtObjBase};

use super::environment::JacoEnv;
use super::error::EnvError;
use super::markov_demo::{KNUCKLES, TIPS};
use super::scene::{SceneIds, lookup};

/// The world body's id: the table and the floor are its geoms.
const WORLD_BODY: usize = 0;

impl JacoEnv {
    /// Whether the robot touches brick 2 now: a MuJoCo contact between brick 2 and a body that
    /// is neither the world (the table, the floor) nor brick 1. The contacts are those of the
    /// last step (or reset, or restore).
    pub fn robot_touches_brick2(&self) -> bool {
        let ids = self.scene().ids();
        let body_of_geom = self.scene().model().geom_bodyid();
        let body = |g: i32| {
            usize::try_from(g)
                .ok()
                .and_then(|g| body_of_geom.get(g))
                .and_then(|&b| usize::try_from(b).ok())
        };
        self.data().contact().iter().any(|c| {
            let (Some(b0), Some(b1)) = (body(c.geom[0]), body(c.geom[1])) else {
                return false;
            };
            let other = if b0 == ids.brick2_body {
                b1
            } else if b1 == ids.brick2_body {
                b0
            } else {
                return false;
            };
            other != WORLD_BODY && other != ids.brick1_body && other != ids.brick2_body
        })
    }
}

impl JacoEnv {
    /// The name of the body geom `geom` belongs to (as in a contact's `geom` pair), if the
    /// geom and its body exist and the body has a name.
    pub fn body_name_of_geom(&self, geom: i32) -> Option<&str> {
        let model = self.scene().model();
        let body = usize::try_from(geom)
            .ok()
            .and_then(|g| model.geom_bodyid().get(g).copied())
            .and_then(|b| usize::try_from(b).ok())?;
        model.id_to_name(MjtObjBase::mjOBJ_BODY, body)
    }
}

/// The geoms [`JacoEnv::finger_clearance_to_brick2`] measures between, found once when the
/// scene loads: the colliding geoms of the fingers' proximal and distal phalanges, and of brick
/// 2. Only geoms that collide (`contype | conaffinity` not 0): the visual meshes around them
/// would read as touching.
#[derive(Debug, Clone)]
pub(crate) struct ClearanceGeoms {
    fingers: Vec<usize>,
    brick2: Vec<usize>,
}

impl ClearanceGeoms {
    /// The lists of `model`; a finger body missing from it is an error.
    pub(crate) fn of(model: &MjModel, ids: &SceneIds) -> Result<Self, EnvError> {
        let bodies = model.geom_bodyid();
        let (contype, conaffinity) = (model.geom_contype(), model.geom_conaffinity());
        let on = |g: usize, b: usize| {
            usize::try_from(bodies[g]).is_ok_and(|x| x == b) && (contype[g] | conaffinity[g]) != 0
        };
        let mut finger_bodies = Vec::with_capacity(TIPS.len() + KNUCKLES.len());
        for name in TIPS.iter().chain(KNUCKLES.iter()) {
            finger_bodies.push(lookup(model, MjtObjBase::mjOBJ_BODY, "body", name)?);
        }
        Ok(Self {
            fingers: (0..bodies.len())
                .filter(|&g| finger_bodies.iter().any(|&b| on(g, b)))
                .collect(),
            brick2: (0..bodies.len())
                .filter(|&g| on(g, ids.brick2_body))
                .collect(),
        })
    }
}

impl JacoEnv {
    /// The distance (metres) between the fingers (their proximal and distal phalanges'
    /// colliding geoms) and brick 2's colliding geoms, MuJoCo's `mj_geomDistance` over every
    /// pair, 0 when they touch or overlap, `max` when none is nearer than `max`. Where a contact
    /// is only yes or no, this is how near the fingers pass.
    pub fn finger_clearance_to_brick2(&mut self, max: f64) -> f64 {
        let (scene, data) = self.scene_and_data_mut();
        let geoms = scene.clearance_geoms();
        let mut nearest = max;
        for &h in &geoms.fingers {
            for &b in &geoms.brick2 {
                if let Ok(d) = data.try_geom_distance(h, b, max, None) {
                    nearest = nearest.min(d);
                }
            }
        }
        nearest.max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use mujoco_rs::prelude::MjtObjBase;

    use crate::random_start::set_free;
    use crate::{EnvConfig, JacoEnv, Scene, Task};

    // Needs MuJoCo and the Jaco assets (`scripts/setup-mujoco.sh`), as the integration tests.
    #[test]
    fn brick_2_on_a_fingertip_is_touched_the_start_and_the_stacked_brick_are_not() {
        let scene = Scene::load().expect("the scene (scripts/setup-mujoco.sh)");
        let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
        env.reset(1).expect("a start");
        assert!(
            !env.robot_touches_brick2(),
            "the start state touches brick 2"
        );
        let ids = *scene.ids();
        // Brick 1 resting on brick 2: a contact between the bricks, not the robot's.
        let b2 = env.reward_state().brick2_pos;
        set_free(
            env.data_mut(),
            ids.brick1_qpos,
            [b2[0], b2[1], b2[2] + crate::scene::BRICK_HEIGHT - 0.001],
            0.0,
        );
        env.data_mut().forward();
        let touching = |env: &JacoEnv, a: usize, b: usize| {
            let model = env.scene().model();
            env.data().contact().iter().any(|c| {
                let pair = (
                    model.geom_bodyid()[c.geom[0] as usize] as usize,
                    model.geom_bodyid()[c.geom[1] as usize] as usize,
                );
                pair == (a, b) || pair == (b, a)
            })
        };
        assert!(
            touching(&env, ids.brick1_body, ids.brick2_body),
            "the bricks do not touch"
        );
        assert!(!env.robot_touches_brick2());
        // Brick 2 moved onto fingertip 2: the robot touches it.
        let tip = scene
            .model()
            .name_to_id(MjtObjBase::mjOBJ_BODY, "hand/b_finger_tip_2")
            .expect("fingertip 2");
        let p = env.data().xpos()[tip];
        set_free(
            env.data_mut(),
            ids.brick2_qpos,
            [p[0], p[1], p[2] - 0.01],
            0.0,
        );
        env.data_mut().forward();
        assert!(
            env.robot_touches_brick2(),
            "brick 2 on the fingertip is not touched"
        );
        // Each contact of brick 2 names its bodies: brick 2 and a finger's.
        let names: Vec<(String, String)> = env
            .data()
            .contact()
            .iter()
            .map(|c| {
                let name = |g: i32| env.body_name_of_geom(g).unwrap_or("?").to_owned();
                (name(c.geom[0]), name(c.geom[1]))
            })
            .collect();
        assert!(
            names
                .iter()
                .any(
                    |(a, b)| (a.as_str(), b.starts_with("hand/b_finger")) == ("brick2", true)
                        || (b.as_str(), a.starts_with("hand/b_finger")) == ("brick2", true)
                ),
            "{names:?}"
        );
        assert_eq!(env.body_name_of_geom(-1), None);
        assert_eq!(env.body_name_of_geom(i32::MAX), None);
        assert_eq!(env.finger_clearance_to_brick2(0.05), 0.0);
        // Brick 2 lowered away from the fingers step by step: the clearance grows with the gap
        // (by no more than the gap grows, up to the distance solver's tolerance) and leaves 0.
        let mut last = 0.0;
        for k in 1..=8 {
            let below = p[2] - crate::scene::BRICK_HEIGHT - 0.01 * f64::from(k);
            set_free(env.data_mut(), ids.brick2_qpos, [p[0], p[1], below], 0.0);
            env.data_mut().forward();
            let c = env.finger_clearance_to_brick2(0.05);
            assert!(c >= last && c <= last + 0.0105, "{k} cm: {c} after {last}");
            last = c;
        }
        assert!(last > 0.0, "8 cm below, the fingers still touch brick 2");
        // Far away: the cap.
        set_free(
            env.data_mut(),
            ids.brick2_qpos,
            [p[0] + 0.5, p[1], 0.0],
            0.0,
        );
        env.data_mut().forward();
        assert_eq!(env.finger_clearance_to_brick2(0.05), 0.05);
    }
}
