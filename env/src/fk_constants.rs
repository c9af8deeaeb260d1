//! Generator of `runtime/src/jaco_kinematics.rs`: the arm's kinematic chain, read from the compiled
//! scene (the same MJCF the simulation runs), written once as f32 constants for the controller's
//! safety envelope (`dex_runtime::envelope`).
//!
//! `trainer/tests/envelope_fk.rs` checks that the committed file equals this output (and rewrites it
//! with `DEX_BLESS=1`) and that the runtime's forward kinematics matches MuJoCo's pinch-site pose.

use std::fmt::Write as _;

use mujoco_rs::prelude::*;

use super::error::EnvError;
use super::scene::{ARM_JOINTS, Scene};

/// One body of the chain from the world to the pinch site's body, as MuJoCo compiled it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainBody {
    /// Position relative to the parent body.
    pub pos: [f64; 3],
    /// Orientation relative to the parent body (w, x, y, z).
    pub quat: [f64; 4],
    /// Arm joint index (0..6) of the body's hinge, if it has one.
    pub joint: Option<usize>,
    /// The hinge's axis in the body frame.
    pub axis: [f64; 3],
    /// Whether the hinge is limited, and its range.
    pub range: Option<[f64; 2]>,
}

/// The chain's bodies from the root outwards, then the site's position and orientation in the last.
pub type PinchChain = (Vec<ChainBody>, [f64; 3], [f64; 4]);

/// The chain world -> pinch site.
pub fn pinch_chain(scene: &Scene) -> Result<PinchChain, EnvError> {
    let model = scene.model();
    let ids = scene.ids();
    let bad = |name: &'static str| EnvError::MissingElement {
        kind: "pinch-site chain",
        name,
    };
    let site = ids.pinch_site;
    let mut body = *model.site_bodyid().get(site).ok_or(bad("site body"))? as usize;
    let mut bodies = Vec::new();
    while body != 0 {
        let pos = *model.body_pos().get(body).ok_or(bad("body_pos"))?;
        let quat = *model.body_quat().get(body).ok_or(bad("body_quat"))?;
        let jntnum = *model.body_jntnum().get(body).ok_or(bad("body_jntnum"))?;
        let (mut joint, mut axis, mut range) = (None, [0.0; 3], None);
        if jntnum > 1 {
            return Err(bad("a body with more than one joint"));
        }
        if jntnum == 1 {
            let jnt = *model.body_jntadr().get(body).ok_or(bad("body_jntadr"))? as usize;
            if model.jnt_type().get(jnt) != Some(&MjtJoint::mjJNT_HINGE) {
                return Err(bad("a joint that is not a hinge"));
            }
            if model.jnt_pos().get(jnt) != Some(&[0.0; 3]) {
                return Err(bad("a hinge off its body's origin"));
            }
            let dof = *model.jnt_dofadr().get(jnt).ok_or(bad("jnt_dofadr"))? as usize;
            let k = ids.joint_dof[..ARM_JOINTS]
                .iter()
                .position(|&d| d == dof)
                .ok_or(bad("a joint that is not an arm joint"))?;
            joint = Some(k);
            axis = *model.jnt_axis().get(jnt).ok_or(bad("jnt_axis"))?;
            if model.jnt_limited().get(jnt).copied().unwrap_or(false) {
                range = Some(*model.jnt_range().get(jnt).ok_or(bad("jnt_range"))?);
            }
        }
        bodies.push(ChainBody {
            pos,
            quat,
            joint,
            axis,
            range,
        });
        body = *model
            .body_parentid()
            .get(body)
            .ok_or(bad("body_parentid"))? as usize;
    }
    bodies.reverse();
    let mut seen: Vec<usize> = bodies.iter().filter_map(|b| b.joint).collect();
    if seen != (0..ARM_JOINTS).collect::<Vec<_>>() {
        seen.sort_unstable();
        return Err(bad("arm joints out of order along the chain"));
    }
    let site_pos = *model.site_pos().get(site).ok_or(bad("site_pos"))?;
    let site_quat = *model.site_quat().get(site).ok_or(bad("site_quat"))?;
    Ok((bodies, site_pos, site_quat))
}

fn f(x: f64) -> String {
    format!("{:?}", x as f32)
}

fn arr(v: &[f64]) -> String {
    let items: Vec<String> = v.iter().map(|&x| f(x)).collect();
    format!("[{}]", items.join(", "))
}

/// The Rust source of `runtime/src/jaco_kinematics.rs`.
pub fn runtime_constants(scene: &Scene) -> Result<String, EnvError> {
    let (bodies, site_pos, site_quat) = pinch_chain(scene)?;
    let mut s = String::new();
    s.push_str(
        "//! The Jaco arm's kinematic chain to the pinch site, generated from the simulation's compiled MJCF\n\
         //! (dm_control's `jaco_arm.xml` + `jaco_hand.xml` in `env/src/scene.rs`) by\n\
         //! `dex_trainer::env::fk_constants`. Do not edit: `DEX_BLESS=1 cargo test -p dex-trainer --release\n\
         //! --test envelope_fk` rewrites it, and that test fails when it differs from the model.\n\
         //! World frame = table frame (surface at z = 0); quaternions are (w, x, y, z).\n\n\
         use crate::kinematics::Link;\n\n",
    );
    let _ = writeln!(
        s,
        "/// Bodies from the world to the pinch site's body (the hand).\npub const CHAIN: [Link; {}] = [",
        bodies.len()
    );
    for b in &bodies {
        let joint = match b.joint {
            Some(k) => format!("Some({k})"),
            None => "None".into(),
        };
        let _ = writeln!(
            s,
            "    Link {{\n        pos: {},\n        quat: {},\n        joint: {joint},\n        axis: {},\n    }},",
            arr(&b.pos),
            arr(&b.quat),
            arr(&b.axis)
        );
    }
    s.push_str("];\n\n");
    let _ = writeln!(
        s,
        "/// The pinch site's position in the hand body.\npub const SITE_POS: [f32; 3] = {};\n",
        arr(&site_pos)
    );
    let _ = writeln!(
        s,
        "/// The pinch site's orientation in the hand body (w, x, y, z).\npub const SITE_QUAT: [f32; 4] = {};\n",
        arr(&site_quat)
    );
    let mut limited = [false; ARM_JOINTS];
    let mut ranges = [[0.0f64; 2]; ARM_JOINTS];
    for b in &bodies {
        if let (Some(k), Some(r)) = (b.joint, b.range) {
            limited[k] = true;
            ranges[k] = r;
        }
    }
    let _ = writeln!(
        s,
        "/// Which arm joints the model limits (the others are continuous).\npub const JOINT_LIMITED: [bool; 6] = {limited:?};\n"
    );
    // One row a line, as rustfmt lays the array out (the file is committed formatted).
    let rows: Vec<String> = ranges
        .iter()
        .map(|r| format!("    {},\n", arr(r)))
        .collect();
    let _ = writeln!(
        s,
        "/// The model's range of each arm joint, radians (`[0.0, 0.0]` where not limited).\npub const JOINT_RANGE: [[f32; 2]; 6] = [\n{}];",
        rows.concat()
    );
    Ok(s)
}
