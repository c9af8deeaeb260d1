//! Forward kinematics of the Jaco arm to the pinch site, in f32 with `nalgebra` (no_std).
//!
//! The chain's constants ([`crate::jaco_kinematics`]) are generated from the simulation's compiled
//! MJCF. Every trigonometric function is the pure-Rust `libm` (never nalgebra's `ComplexField`,
//! which takes the platform's maths under `std`) and nalgebra's products are plain multiply-adds
//! that Rust does not fuse, so the host and the Cortex-M4F give the same bits.
//!
//! Two evaluations of the same chain:
//!
//! - [`pinch_pose`]: position and orientation, with quaternions and one [`sin_cos`] of each half
//!   angle per call (the task features use it).
//! - [`pinch_position_trig`]: the position alone from each joint's sine and cosine
//!   ([`JointTrig`]), with the links' constant rotations as 3x3 matrices folded from the end of
//!   the chain towards its base: no trigonometry and ~200 f32 operations per call. The safety
//!   envelope uses it. [`JointTrig::of`] takes one [`sin_cos`] per joint (f32 range reduction and
//!   polynomials: the `libm` functions compute in f64, which the Cortex-M4F's single-precision
//!   FPU emulates in software); [`JointTrig::shifted`] gives the angles `q + d` from those by the
//!   angle-addition formulas.
//!
//! Both are exact up to f32 rounding and agree to well under a micrometre
//! (`runtime/tests/kinematics.rs` states the bound it checks).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::jaco_kinematics::{CHAIN, SITE_POS, SITE_QUAT};

/// Largest `|x|` (radians) whose sine and cosine [`sin_cos`] computes in f32; larger or
/// non-finite arguments go through `libm::sinf` and `libm::cosf`.
pub const SIN_COS_RANGE: f32 = 256.0;

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
            let (s, c) = sin_cos(half);
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

/// The sine and cosine of each arm joint's angle: all that [`pinch_position_trig`] needs of the
/// angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointTrig {
    /// Sine of each joint's angle.
    pub sin: [f32; ARM_JOINTS],
    /// Cosine of each joint's angle.
    pub cos: [f32; ARM_JOINTS],
}

impl JointTrig {
    /// The sines and cosines of the angles `q` (radians): one [`sin_cos`] per joint.
    pub fn of(q: &[f32; ARM_JOINTS]) -> Self {
        let mut t = JointTrig {
            sin: [0.0; ARM_JOINTS],
            cos: [0.0; ARM_JOINTS],
        };
        for (j, &a) in q.iter().enumerate() {
            (t.sin[j], t.cos[j]) = sin_cos(a);
        }
        t
    }

    /// The sines and cosines of the angles `q + d`, where `self` holds those of `q`:
    /// `sin(q + d) = sin q cos d + cos q sin d`, `cos(q + d) = cos q cos d - sin q sin d`, with
    /// [`sin_cos`] of `d`. The sum `q + d` itself is never rounded to f32.
    pub fn shifted(&self, d: &[f32; ARM_JOINTS]) -> Self {
        let mut t = *self;
        for (j, &dj) in d.iter().enumerate() {
            let (sd, cd) = sin_cos(dj);
            let (s, c) = (self.sin[j], self.cos[j]);
            t.sin[j] = s * cd + c * sd;
            t.cos[j] = c * cd - s * sd;
        }
        t
    }
}

/// pi/2 in three parts (Cody-Waite): the first two have at most 12 significant bits, so `k * part`
/// is exact for `|k| < 2^12`.
const PIO2: [f32; 3] = [1.570_312_5, 4.837_513e-4, 7.549_79e-8];

/// Sine and cosine of `x` (radians) in f32 arithmetic (nothing fused, fixed order): `x = k pi/2 +
/// r` with `k` the nearest integer and `r` from three parts of pi/2, then Taylor polynomials of
/// degree 9 (sine) and 10 (cosine) on `|r| <= pi/4` (Horner form in `r^2`; truncation below
/// 2e-9), swapped and negated by the quadrant of `k`. Within 1.5e-7 of the exact values for
/// `|x| <=` [`SIN_COS_RANGE`] (`runtime/tests/kinematics.rs`); beyond it, and for NaN or
/// infinities, `libm::sinf` and `libm::cosf`. The `libm` functions compute in f64, which the Cortex-M4F's
/// single-precision FPU emulates in software; this costs a few dozen instructions.
pub fn sin_cos(x: f32) -> (f32, f32) {
    if x.is_nan() || libm::fabsf(x) > SIN_COS_RANGE {
        return (libm::sinf(x), libm::cosf(x));
    }
    let half = if x >= 0.0 { 0.5 } else { -0.5 };
    let k = (x * core::f32::consts::FRAC_2_PI + half) as i32;
    let kf = k as f32;
    let r = ((x - kf * PIO2[0]) - kf * PIO2[1]) - kf * PIO2[2];
    let r2 = r * r;
    let s = r
        * (1.0
            - r2 * (1.0 / 6.0)
                * (1.0
                    - r2 * (1.0 / 20.0) * (1.0 - r2 * (1.0 / 42.0) * (1.0 - r2 * (1.0 / 72.0)))));
    let c = 1.0
        - r2 * 0.5
            * (1.0
                - r2 * (1.0 / 12.0)
                    * (1.0
                        - r2 * (1.0 / 30.0)
                            * (1.0 - r2 * (1.0 / 56.0) * (1.0 - r2 * (1.0 / 90.0)))));
    match k & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// One link of the chain as [`pinch_position_trig`] uses it.
#[derive(Clone, Copy)]
struct MatrixLink {
    pos: [f32; 3],
    /// The constant rotation, row-major.
    rot: [[f32; 3]; 3],
    joint: Option<usize>,
}

/// The rotation matrix (row-major) of quaternion `q` (w, x, y, z), computed in f64 and rounded
/// once to f32.
const fn quat_matrix(q: [f32; 4]) -> [[f32; 3]; 3] {
    let (w, x, y, z) = (q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64);
    [
        [
            (1.0 - 2.0 * (y * y + z * z)) as f32,
            (2.0 * (x * y - w * z)) as f32,
            (2.0 * (x * z + w * y)) as f32,
        ],
        [
            (2.0 * (x * y + w * z)) as f32,
            (1.0 - 2.0 * (x * x + z * z)) as f32,
            (2.0 * (y * z - w * x)) as f32,
        ],
        [
            (2.0 * (x * z - w * y)) as f32,
            (2.0 * (y * z + w * x)) as f32,
            (1.0 - 2.0 * (x * x + y * y)) as f32,
        ],
    ]
}

/// [`CHAIN`] with matrices. Fails to compile when a hinge's axis is not the body's +z (the
/// generated Jaco chain's every hinge) or names a joint past [`ARM_JOINTS`]:
/// [`pinch_position_trig`] rotates about z only.
const MATRIX_CHAIN: [MatrixLink; CHAIN.len()] = {
    let mut out = [MatrixLink {
        pos: [0.0; 3],
        rot: [[0.0; 3]; 3],
        joint: None,
    }; CHAIN.len()];
    let mut k = 0;
    while k < CHAIN.len() {
        let link = &CHAIN[k];
        if let Some(j) = link.joint {
            assert!(j < ARM_JOINTS, "a hinge names a joint past the arm's");
            let a = link.axis;
            assert!(
                a[0] == 0.0 && a[1] == 0.0 && a[2] == 1.0,
                "pinch_position_trig needs every hinge axis to be the body's +z"
            );
        }
        out[k] = MatrixLink {
            pos: link.pos,
            rot: quat_matrix(link.quat),
            joint: link.joint,
        };
        k += 1;
    }
    out
};

/// The pinch site's position from each arm joint's sine and cosine: `p = pos_0 + R_0 H_0 (pos_1
/// + R_1 H_1 (... (site)))`, evaluated from the site towards the base (a matrix-vector product per
/// link, a plane rotation per hinge, each row summed left to right). The same position as
/// [`pinch_pose`] up to f32 rounding, without its quaternion products or trigonometry.
pub fn pinch_position_trig(t: &JointTrig) -> Vector3<f32> {
    let mut v = SITE_POS;
    for link in MATRIX_CHAIN.iter().rev() {
        if let Some(j) = link.joint {
            let (s, c) = (
                t.sin.get(j).copied().unwrap_or(0.0),
                t.cos.get(j).copied().unwrap_or(1.0),
            );
            v = [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]];
        }
        let r = &link.rot;
        v = [
            link.pos[0] + (r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2]),
            link.pos[1] + (r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2]),
            link.pos[2] + (r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2]),
        ];
    }
    Vector3::from(v)
}
