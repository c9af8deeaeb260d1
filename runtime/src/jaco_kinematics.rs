//! The Jaco arm's kinematic chain to the pinch site, generated from the simulation's compiled MJCF
//! (dm_control's `jaco_arm.xml` + `jaco_hand.xml` in `env/src/scene.rs`) by
//! `dex_trainer::env::fk_constants`. Do not edit: `DEX_BLESS=1 cargo test -p dex-trainer --release
//! --test envelope_fk` rewrites it, and that test fails when it differs from the model.
//! World frame = table frame (surface at z = 0); quaternions are (w, x, y, z).

use crate::kinematics::Link;

/// Bodies from the world to the pinch site's body (the hand).
pub const CHAIN: [Link; 8] = [
    Link {
        pos: [0.0, 0.4, 0.0],
        quat: [1.0, 0.0, 0.0, 0.0],
        joint: None,
        axis: [0.0, 0.0, 0.0],
    },
    Link {
        pos: [0.0, 0.0, 0.15675],
        quat: [0.0, 0.0, 1.0, 0.0],
        joint: Some(0),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, 0.0016, -0.11875],
        quat: [0.0, 0.0, -0.70710677, 0.70710677],
        joint: Some(1),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, -0.41, 0.0],
        quat: [0.0, 0.0, 1.0, 0.0],
        joint: Some(2),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, 0.2073, -0.0114],
        quat: [0.0, 0.0, -0.70710677, 0.70710677],
        joint: Some(3),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, -0.03703, -0.06414],
        quat: [0.0, 0.0, 0.5000002, 0.8660253],
        joint: Some(4),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, -0.03703, -0.06414],
        quat: [0.0, 0.0, 0.5000002, 0.8660253],
        joint: Some(5),
        axis: [0.0, 0.0, 1.0],
    },
    Link {
        pos: [0.0, 0.0, 0.0],
        quat: [-1.0, 0.0, 0.0, 0.0],
        joint: None,
        axis: [0.0, 0.0, 0.0],
    },
];

/// The pinch site's position in the hand body.
pub const SITE_POS: [f32; 3] = [0.015, 0.0024, -0.193];

/// The pinch site's orientation in the hand body (w, x, y, z).
pub const SITE_QUAT: [f32; 4] = [0.0, 0.70710677, 0.70710677, 0.0];

/// Which arm joints the model limits (the others are continuous).
pub const JOINT_LIMITED: [bool; 6] = [false, true, true, false, false, false];

/// The model's range of each arm joint, radians (`[0.0, 0.0]` where not limited).
pub const JOINT_RANGE: [[f32; 2]; 6] = [
    [0.0, 0.0],
    [0.820305, 5.462881],
    [0.331613, 5.951573],
    [0.0, 0.0],
    [0.0, 0.0],
    [0.0, 0.0],
];
