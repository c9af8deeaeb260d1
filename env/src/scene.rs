//! Scene composition: table, Kinova Jaco arm + 3-finger hand, two Duplo 2x4 bricks, nine velocity actuators.
//!
//! The scene MJCF is our own; it pulls dm_control's `jaco_arm.xml` and `duplo2x4.xml` in with `<attach>`
//! and the hand onto the arm's `wristsite` with mjSpec (plain MJCF cannot attach to a body that itself came
//! from an attached model). A child's `<option>` is dropped on attach, so dm_control's physics options are
//! restated here: 2 ms timestep, elliptic friction cones, 5 noslip iterations, no native CCD.
//!
//! Frames: the world frame *is* the table frame (table surface at z = 0); the arm base stands at
//! (0, 0.4, 0). Brick positions are their body origins, the centre of the brick's bottom face.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use mujoco_rs::prelude::*;

use super::contacts::ClearanceGeoms;
use super::error::EnvError;

/// Height of the pinch site above brick 1's origin at which the demonstrator closes the fingers.
pub const GRASP_DEPTH: f64 = 0.012;
/// Physics step in seconds (dm_control: 2 ms).
pub const PHYSICS_TIMESTEP: f64 = 0.002;
/// Physics steps per control step: 25 x 2 ms = 50 ms (20 Hz).
pub const SUBSTEPS: usize = 25;
/// Control step in seconds.
pub const CONTROL_TIMESTEP: f64 = PHYSICS_TIMESTEP * SUBSTEPS as f64;
/// Where the arm base stands on the table (dm_control's `ARM_OFFSET`).
pub const ARM_BASE: [f64; 3] = [0.0, 0.4, 0.0];
/// Height of a Duplo brick's collision box (its top face, where the next brick sits), metres.
pub const BRICK_HEIGHT: f64 = 0.0192;
/// Half extents of the brick's collision box (x: narrow side, y: long side, z), metres.
pub const BRICK_HALF_EXTENTS: [f64; 3] = [0.0159, 0.0318, 0.0096];

/// Number of arm joints.
pub const ARM_JOINTS: usize = 6;
/// Number of finger joints.
pub const FINGER_JOINTS: usize = 3;

const ARM_JOINT_NAMES: [&str; ARM_JOINTS] = [
    "arm/joint_1",
    "arm/joint_2",
    "arm/joint_3",
    "arm/joint_4",
    "arm/joint_5",
    "arm/joint_6",
];
const FINGER_JOINT_NAMES: [&str; FINGER_JOINTS] =
    ["hand/finger_1", "hand/finger_2", "hand/finger_3"];

/// Where the third-party MJCF files live (filled by `scripts/setup-mujoco.sh`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AssetPaths {
    /// Folder holding `kinova/jaco_arm.xml`, `kinova/jaco_hand.xml` and `duplo/duplo2x4.xml`.
    pub root: PathBuf,
}

impl AssetPaths {
    /// Environment variable that overrides the asset folder.
    pub const ENV_VAR: &'static str = "DEX_MUJOCO_ASSETS";

    /// `$DEX_MUJOCO_ASSETS` if set, else the repository's `third_party/assets`.
    pub fn locate() -> Self {
        let root = std::env::var_os(Self::ENV_VAR)
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../third_party/assets"));
        Self { root }
    }

    fn file(&self, rel: &str) -> Result<PathBuf, EnvError> {
        let path = self.root.join(rel);
        if path.is_file() {
            Ok(path)
        } else {
            Err(EnvError::AssetsMissing { path })
        }
    }
}

impl Default for AssetPaths {
    fn default() -> Self {
        Self::locate()
    }
}

/// Indices into the compiled model that the environment reads every step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SceneIds {
    /// `qpos` address of each arm joint, then each finger joint.
    pub joint_qpos: [usize; ARM_JOINTS + FINGER_JOINTS],
    /// `qvel` address of each arm joint, then each finger joint.
    pub joint_dof: [usize; ARM_JOINTS + FINGER_JOINTS],
    /// `qpos` address of brick 1's free joint (3 position + 4 quaternion).
    pub brick1_qpos: usize,
    /// `qvel` address of brick 1's free joint.
    pub brick1_dof: usize,
    /// `qpos` address of brick 2's free joint.
    pub brick2_qpos: usize,
    /// `qvel` address of brick 2's free joint.
    pub brick2_dof: usize,
    /// Body id of brick 1.
    pub brick1_body: usize,
    /// Body id of brick 2.
    pub brick2_body: usize,
    /// Site id of the hand's pinch site.
    pub pinch_site: usize,
}

/// The compiled scene: one `MjModel` shared by every environment (it is `Sync`), plus its indices.
#[derive(Debug, Clone)]
pub struct Scene {
    model: Arc<MjModel>,
    ids: SceneIds,
    clearance: ClearanceGeoms,
}

impl Scene {
    /// Builds the scene from the assets found by [`AssetPaths::locate`].
    pub fn load() -> Result<Self, EnvError> {
        Self::from_assets(&AssetPaths::locate())
    }

    /// Builds the scene from the given asset folder.
    pub fn from_assets(assets: &AssetPaths) -> Result<Self, EnvError> {
        let mut spec = compose_spec(assets)?;
        let model = spec.compile().map_err(|source| EnvError::Scene {
            stage: "compiling",
            source,
        })?;
        let ids = scene_ids(&model)?;
        let clearance = ClearanceGeoms::of(&model, &ids)?;
        Ok(Self {
            model: Arc::new(model),
            ids,
            clearance,
        })
    }

    /// The shared compiled model.
    pub fn model(&self) -> &Arc<MjModel> {
        &self.model
    }

    /// Indices of the joints, bricks and sites the environment uses.
    pub fn ids(&self) -> &SceneIds {
        &self.ids
    }

    /// The colliding geoms of the fingers and of brick 2, for
    /// [`crate::JacoEnv::finger_clearance_to_brick2`].
    pub(crate) fn clearance_geoms(&self) -> &ClearanceGeoms {
        &self.clearance
    }

    /// A fresh simulation state for this model (one per environment / thread).
    pub fn make_data(&self) -> MjData<Arc<MjModel>> {
        MjData::new(Arc::clone(&self.model))
    }
}

/// The uncompiled scene: our scene MJCF with the arm and bricks attached, and the hand attached to the arm's
/// `wristsite` through mjSpec. Exposed so tools can save it as one MJCF file (`MjSpec::save_xml`).
pub fn compose_spec(assets: &AssetPaths) -> Result<MjSpec, EnvError> {
    let arm = assets.file("kinova/jaco_arm.xml")?;
    let hand = assets.file("kinova/jaco_hand.xml")?;
    let duplo = assets.file("duplo/duplo2x4.xml")?;
    let xml = scene_xml(&arm, &duplo);
    let mut spec = MjSpec::from_xml_string(&xml).map_err(|source| EnvError::Scene {
        stage: "parsing the scene MJCF",
        source,
    })?;
    let mut hand_spec = MjSpec::from_xml(&hand).map_err(|source| EnvError::Scene {
        stage: "parsing jaco_hand.xml",
        source,
    })?;
    let hand_body = hand_spec.body_mut("hand").ok_or(EnvError::MissingElement {
        kind: "body",
        name: "hand",
    })?;
    spec.site_mut("arm/wristsite")
        .ok_or(EnvError::MissingElement {
            kind: "site",
            name: "arm/wristsite",
        })?
        .attach_by_deep_copy(hand_body, "hand/", "")
        .map_err(|source| EnvError::Scene {
            stage: "attaching the hand to arm/wristsite",
            source,
        })?;
    Ok(spec)
}

pub(crate) fn lookup(
    model: &MjModel,
    kind: MjtObjBase,
    kind_name: &'static str,
    name: &'static str,
) -> Result<usize, EnvError> {
    model
        .name_to_id(kind, name)
        .ok_or(EnvError::MissingElement {
            kind: kind_name,
            name,
        })
}

fn scene_ids(model: &MjModel) -> Result<SceneIds, EnvError> {
    let qposadr = model.jnt_qposadr();
    let dofadr = model.jnt_dofadr();
    let mut joint_qpos = [0; ARM_JOINTS + FINGER_JOINTS];
    let mut joint_dof = [0; ARM_JOINTS + FINGER_JOINTS];
    for (i, name) in ARM_JOINT_NAMES
        .iter()
        .chain(FINGER_JOINT_NAMES.iter())
        .enumerate()
    {
        let j = lookup(model, MjtObjBase::mjOBJ_JOINT, "joint", name)?;
        joint_qpos[i] = qposadr[j] as usize;
        joint_dof[i] = dofadr[j] as usize;
    }
    // The actuators must be in the interface's action order.
    for (i, joint) in dex_runtime::interface::ACTION_JOINTS.iter().enumerate() {
        if model.name_to_id(MjtObjBase::mjOBJ_ACTUATOR, joint.name) != Some(i) {
            return Err(EnvError::MissingElement {
                kind: "actuator (in ACTION_JOINTS order)",
                name: joint.name,
            });
        }
    }
    let brick1_joint = lookup(model, MjtObjBase::mjOBJ_JOINT, "joint", "brick1")?;
    let brick2_joint = lookup(model, MjtObjBase::mjOBJ_JOINT, "joint", "brick2")?;
    Ok(SceneIds {
        joint_qpos,
        joint_dof,
        brick1_qpos: qposadr[brick1_joint] as usize,
        brick1_dof: dofadr[brick1_joint] as usize,
        brick2_qpos: qposadr[brick2_joint] as usize,
        brick2_dof: dofadr[brick2_joint] as usize,
        brick1_body: lookup(model, MjtObjBase::mjOBJ_BODY, "body", "brick1")?,
        brick2_body: lookup(model, MjtObjBase::mjOBJ_BODY, "body", "brick2")?,
        pinch_site: lookup(model, MjtObjBase::mjOBJ_SITE, "site", "hand/pinchsite")?,
    })
}

/// The scene MJCF. Actuators follow `dex_runtime::interface::ACTION_JOINTS` in order, with dm_control's
/// velocity gains (`kv`) and force limits.
fn scene_xml(arm: &Path, duplo: &Path) -> String {
    let arm = arm.display();
    let duplo = duplo.display();
    format!(
        r#"<mujoco model="jaco_stack">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_TIMESTEP}" cone="elliptic" noslip_iterations="5">
    <flag nativeccd="disable" multiccd="disable"/>
  </option>
  <visual><global offwidth="640" offheight="480"/></visual>
  <asset>
    <model name="arm" file="{arm}"/>
    <model name="duplo" file="{duplo}"/>
    <texture name="grid" type="2d" builtin="checker" rgb1=".35 .35 .38" rgb2=".3 .3 .33" width="300" height="300"/>
    <material name="table" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light pos="0 -0.5 1.5" dir="0 0.3 -1" directional="true"/>
    <camera name="front" pos="0 -0.42 0.33" xyaxes="1 0 0 0 0.55 0.83"/>
    <geom name="table" type="plane" size="1 1 0.1" material="table" friction="0.4"
          solref="0.01 1" solimp="0.99 0.999 0.001"/>
    <frame pos="{ax} {ay} {az}">
      <attach model="arm" body="b_base" prefix="arm/"/>
    </frame>
    <body name="brick1" pos="0 -0.05 0">
      <freejoint name="brick1"/>
      <attach model="duplo" prefix="brick1/"/>
    </body>
    <body name="brick2" pos="0 0.05 0">
      <freejoint name="brick2"/>
      <attach model="duplo" prefix="brick2/"/>
    </body>
  </worldbody>
  <actuator>
    <velocity name="arm_joint_1" joint="arm/joint_1" kv="500" ctrlrange="-0.628319 0.628319" forcerange="-30.5 30.5"/>
    <velocity name="arm_joint_2" joint="arm/joint_2" kv="500" ctrlrange="-0.628319 0.628319" forcerange="-30.5 30.5"/>
    <velocity name="arm_joint_3" joint="arm/joint_3" kv="500" ctrlrange="-0.628319 0.628319" forcerange="-30.5 30.5"/>
    <velocity name="arm_joint_4" joint="arm/joint_4" kv="500" ctrlrange="-0.837758 0.837758" forcerange="-6.8 6.8"/>
    <velocity name="arm_joint_5" joint="arm/joint_5" kv="500" ctrlrange="-0.837758 0.837758" forcerange="-6.8 6.8"/>
    <velocity name="arm_joint_6" joint="arm/joint_6" kv="500" ctrlrange="-0.837758 0.837758" forcerange="-6.8 6.8"/>
    <velocity name="finger_1" joint="hand/finger_1" kv="10" ctrlrange="-5 5" forcerange="-1 1"/>
    <velocity name="finger_2" joint="hand/finger_2" kv="10" ctrlrange="-5 5" forcerange="-1 1"/>
    <velocity name="finger_3" joint="hand/finger_3" kv="10" ctrlrange="-5 5" forcerange="-1 1"/>
  </actuator>
</mujoco>"#,
        ax = ARM_BASE[0],
        ay = ARM_BASE[1],
        az = ARM_BASE[2],
    )
}
