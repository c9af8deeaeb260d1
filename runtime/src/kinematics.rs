//! Forward kinematics of the Jaco arm to the pinch site, in f32 with `nalgebra` (no_std).
//!
//! The chain's constants ([`crate::jaco_kinematics`]) are generated from the simulation's compiled
//! MJCF. Every trigonometric function is the pure-Rust `libm` (never nalgebra's `ComplexField`,
//! which takes the platform's maths under `std`) and nalgebra's products are plain multiply-adds
//! that Rust does not fuse, so the host and the Cortex-M4F give the same bits.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::jaco_kinematics::{CHAIN, SITE_POS, SITE_QUAT};

/// Number of arm joints in the chain.
pub const ARM_JOINTS: usize = 6;

/// One body of the kinematic chain, relative to its parent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Link {
    /// Position of the body in its parent's frame, metres.
    pub pos: [f32; 3],
    /// Orientation of the body in its parent's frame (w, x, y, z), unit length.
    pub quat: [f32; 4],
    /// Arm joint (index into the joint angles) of the body's hinge at its origin, if any.
    pub joint: Option<usize>,
    /// The hinge's unit axis in the body frame.
    pub axis: [f32; 3],
}

/// A rigid pose: position and orientation in the world (table) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position, metres.
    pub pos: Vector3<f32>,
    /// Orientation.
    pub rot: UnitQuaternion<f32>,
}

fn quat(q: &[f32; 4]) -> UnitQuaternion<f32> {
    // The constants are unit quaternions already: no normalisation (no square root).
    UnitQuaternion::new_unchecked(Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// The pinch site's pose for arm joint angles `q` (radians).
pub fn pinch_pose(q: &[f32; ARM_JOINTS]) -> Pose {
    let mut pos = Vector3::zeros();
    let mut rot = UnitQuaternion::identity();
    for link in &CHAIN {
        pos += rot * Vector3::from(link.pos);
        rot *= quat(&link.quat);
        if let Some(k) = link.joint {
            let half = q.get(k).copied().unwrap_or(0.0) * 0.5;
            let (s, c) = (libm::sinf(half), libm::cosf(half));
            let a = link.axis;
            rot *= UnitQuaternion::new_unchecked(Quaternion::new(c, a[0] * s, a[1] * s, a[2] * s));
        }
    }
    pos += rot * Vector3::from(SITE_POS);
    rot *= quat(&SITE_QUAT);
    Pose { pos, rot }
}

/// The pinch site's position only (the envelope's constraints need no orientation).
pub fn pinch_position(q: &[f32; ARM_JOINTS]) -> Vector3<f32> {
    pinch_pose(q).pos
}
