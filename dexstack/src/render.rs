//! What the Python renderer (`python/dexstack/renderer.py`) needs from Rust, and nothing more: the
//! scene's compiled model as MuJoCo's binary model file (MJB, the very `MjModel` every environment
//! steps, bit for bit), the names of its cameras, and an environment's MuJoCo state.
//!
//! The renderer loads the MJB into the `mujoco` wheel (the same MuJoCo version), copies an
//! environment's state into its own `MjData` with `mj_setState`, calls `mj_forward` and draws: the
//! frame shows the state the policy sees, not a re-simulation. None of this runs unless Python
//! renders: an environment made without a render mode never calls into this module.

use dex_env::JacoEnv;
use mujoco_rs::prelude::*;

use crate::episode::scene;
use crate::error::{Error, Result};

/// The state elements copied to the renderer: MuJoCo's `mjSTATE_INTEGRATION` (time, positions,
/// velocities, activations, controls, warm start, applied forces, mocap poses, ...), everything
/// `mj_step` reads. `mj_forward` on it gives exactly the kinematics of the Rust environment.
pub const STATE_SPEC: u32 = MjtState::mjSTATE_INTEGRATION as u32;

/// The version of the MuJoCo library the environments link (`scripts/setup-mujoco.sh`); the
/// renderer's `mujoco` wheel must be the same.
pub fn mujoco_version() -> &'static str {
    mujoco_rs::mujoco_version()
}

/// The scene's compiled model as MJB bytes (`mj_saveModel`): loaded by the `mujoco` wheel of the
/// same version, it is the same model, every number included.
pub fn scene_mjb() -> Result<Vec<u8>> {
    let model = scene()?.model();
    let mut buffer = vec![0u8; model.size()];
    model
        .save_to_buffer(&mut buffer)
        .map_err(|e| Error::Render(format!("cannot save the scene as a binary model: {e}")))?;
    Ok(buffer)
}

/// The names of the scene's cameras, in id order (an unnamed camera gives an empty name).
pub fn camera_names() -> Result<Vec<String>> {
    let model = scene()?.model();
    let count = usize::try_from(model.ncam()).unwrap_or(0);
    Ok((0..count)
        .map(|id| {
            model
                .id_to_name(MjtObjBase::mjOBJ_CAMERA, id)
                .unwrap_or_default()
                .to_owned()
        })
        .collect())
}

/// The MuJoCo state of `env` in the [`STATE_SPEC`] layout (`mj_getState`).
pub fn state(env: &JacoEnv) -> Box<[f64]> {
    env.data().state(STATE_SPEC)
}

/// [`state`] as native-endian float64 bytes, the form Python reads with numpy.
pub fn state_bytes(env: &JacoEnv) -> Vec<u8> {
    state(env).iter().flat_map(|v| v.to_ne_bytes()).collect()
}
