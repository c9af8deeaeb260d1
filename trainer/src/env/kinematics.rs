//! Pinch-site kinematics for the arm: pose, 6x6 Jacobian, orientation error and damped least squares.
//!
//! Used by the start-state sampler (place the hand at a random pose by inverse kinematics) and by the
//! scripted demonstrator (resolved-rate control of the pinch site).

use std::sync::Arc;

use mujoco_rs::prelude::*;

use super::scene::{ARM_JOINTS, SceneIds};

/// A 6-vector: linear part then angular part, or one per arm joint.
pub type Vec6 = [f64; 6];

/// The pinch site's position and row-major orientation matrix (after kinematics).
pub fn pinch_pose(data: &MjData<Arc<MjModel>>, ids: &SceneIds) -> ([f64; 3], [f64; 9]) {
    let pos = data
        .site_xpos()
        .get(ids.pinch_site)
        .copied()
        .unwrap_or([0.0; 3]);
    let mat = data
        .site_xmat()
        .get(ids.pinch_site)
        .copied()
        .unwrap_or([0.0; 9]);
    (pos, mat)
}

/// Row-major rotation of a pinch site that points straight down with its closing axis (site x) at `yaw`.
pub fn down_rotation(yaw: f64) -> [f64; 9] {
    let (s, c) = yaw.sin_cos();
    [c, s, 0.0, s, -c, 0.0, 0.0, 0.0, -1.0]
}

/// Rotation vector (axis times angle, small-angle form) that turns `current` towards `target`.
pub fn orientation_error(current: &[f64; 9], target: &[f64; 9]) -> [f64; 3] {
    let mut e = [0.0; 3];
    for col in 0..3 {
        let r = [current[col], current[3 + col], current[6 + col]];
        let t = [target[col], target[3 + col], target[6 + col]];
        e[0] += 0.5 * (r[1] * t[2] - r[2] * t[1]);
        e[1] += 0.5 * (r[2] * t[0] - r[0] * t[2]);
        e[2] += 0.5 * (r[0] * t[1] - r[1] * t[0]);
    }
    e
}

/// The pinch site's 6x6 Jacobian over the arm joints: rows 0-2 linear, 3-5 angular velocity.
pub fn arm_jacobian(data: &MjData<Arc<MjModel>>, ids: &SceneIds) -> [Vec6; 6] {
    let nv = data.model().ffi().nv as usize;
    let mut jac = [[0.0; 6]; 6];
    let Ok((jacp, jacr)) = data.try_jac_site(true, true, ids.pinch_site) else {
        return jac;
    };
    for (j, &dof) in ids.joint_dof[..ARM_JOINTS].iter().enumerate() {
        for r in 0..3 {
            jac[r][j] = jacp.get(r * nv + dof).copied().unwrap_or(0.0);
            jac[3 + r][j] = jacr.get(r * nv + dof).copied().unwrap_or(0.0);
        }
    }
    jac
}

/// Damped least squares: `J^T (J J^T + lambda^2 I)^-1 e`, the joint step that best achieves `e`.
pub fn damped_least_squares(jac: &[Vec6; 6], e: &Vec6, lambda: f64) -> Vec6 {
    let mut a = [[0.0; 6]; 6];
    for i in 0..6 {
        for k in 0..6 {
            a[i][k] = (0..6).map(|j| jac[i][j] * jac[k][j]).sum::<f64>();
        }
        a[i][i] += lambda * lambda;
    }
    let y = solve6(a, *e);
    let mut dq = [0.0; 6];
    for (j, out) in dq.iter_mut().enumerate() {
        *out = (0..6).map(|i| jac[i][j] * y[i]).sum();
    }
    dq
}

/// Gaussian elimination with partial pivoting; `a` is symmetric positive definite here.
fn solve6(mut a: [Vec6; 6], mut b: Vec6) -> Vec6 {
    for col in 0..6 {
        let mut piv = col;
        for r in col + 1..6 {
            if a[r][col].abs() > a[piv][col].abs() {
                piv = r;
            }
        }
        a.swap(col, piv);
        b.swap(col, piv);
        let d = a[col][col];
        if d.abs() < 1e-14 {
            return [0.0; 6];
        }
        for r in col + 1..6 {
            let f = a[r][col] / d;
            let pivot_row = a[col];
            for (x, p) in a[r][col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = [0.0; 6];
    for r in (0..6).rev() {
        let s: f64 = (r + 1..6).map(|c| a[r][c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    x
}

/// Pose error of the pinch site: (target position - position, orientation error).
pub fn pose_error(
    data: &MjData<Arc<MjModel>>,
    ids: &SceneIds,
    pos: &[f64; 3],
    rot: &[f64; 9],
) -> Vec6 {
    let (p, m) = pinch_pose(data, ids);
    let o = orientation_error(&m, rot);
    [
        pos[0] - p[0],
        pos[1] - p[1],
        pos[2] - p[2],
        o[0],
        o[1],
        o[2],
    ]
}

/// Moves the arm joints (positions only) until the pinch site reaches `pos` with orientation `rot`.
/// Returns the final position error norm in metres and orientation error norm in radians.
/// Joint limits are respected by clamping. Leaves kinematics (not dynamics) up to date.
pub fn solve_ik(
    data: &mut MjData<Arc<MjModel>>,
    ids: &SceneIds,
    pos: &[f64; 3],
    rot: &[f64; 9],
    iterations: usize,
) -> (f64, f64) {
    let (limited, ranges) = joint_ranges(data.model(), ids);
    for _ in 0..iterations {
        data.kinematics();
        data.com_pos();
        let err = pose_error(data, ids, pos, rot);
        if norm3(&err[..3]) < 1e-4 && norm3(&err[3..]) < 1e-3 {
            break;
        }
        let jac = arm_jacobian(data, ids);
        let dq = damped_least_squares(&jac, &err, 0.05);
        let qpos = data.qpos_mut();
        for (j, step) in dq.iter().enumerate() {
            let adr = ids.joint_qpos[j];
            if let Some(q) = qpos.get_mut(adr) {
                *q += step.clamp(-0.3, 0.3);
                if limited[j] {
                    *q = q.clamp(ranges[j][0], ranges[j][1]);
                }
            }
        }
    }
    data.kinematics();
    data.com_pos();
    let err = pose_error(data, ids, pos, rot);
    (norm3(&err[..3]), norm3(&err[3..]))
}

fn joint_ranges(model: &MjModel, ids: &SceneIds) -> ([bool; ARM_JOINTS], [[f64; 2]; ARM_JOINTS]) {
    let mut limited = [false; ARM_JOINTS];
    let mut ranges = [[0.0; 2]; ARM_JOINTS];
    for j in 0..ARM_JOINTS {
        // Joint ids of the arm are found through the dof's joint.
        let dof = ids.joint_dof[j];
        let Some(&jnt) = model.dof_jntid().get(dof) else {
            continue;
        };
        let jnt = jnt as usize;
        limited[j] = model.jnt_limited().get(jnt).copied().unwrap_or(false);
        ranges[j] = model.jnt_range().get(jnt).copied().unwrap_or([0.0; 2]);
    }
    (limited, ranges)
}

/// Euclidean norm of a 3-slice.
pub fn norm3(v: &[f64]) -> f64 {
    v.iter().take(3).map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn down_rotation_is_proper_and_points_down() {
        let m = down_rotation(0.7);
        assert!((m[8] + 1.0).abs() < 1e-12, "site z axis is -z");
        let det = m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6])
            + m[2] * (m[3] * m[7] - m[4] * m[6]);
        assert!((det - 1.0).abs() < 1e-12);
        assert_eq!(orientation_error(&m, &m), [0.0; 3]);
        // A small yaw difference shows up as a rotation about z.
        let e = orientation_error(&down_rotation(0.0), &down_rotation(0.01));
        assert!(e[0].abs() < 1e-12 && e[1].abs() < 1e-12 && (e[2] - 0.01f64.sin()).abs() < 1e-9);
    }

    #[test]
    fn dls_inverts_a_well_conditioned_jacobian() {
        let mut jac = [[0.0; 6]; 6];
        for (i, row) in jac.iter_mut().enumerate() {
            row[i] = 2.0;
            row[(i + 1) % 6] = 0.5;
        }
        let e = [0.1, -0.2, 0.3, 0.0, 0.05, -0.1];
        let dq = damped_least_squares(&jac, &e, 1e-6);
        for i in 0..6 {
            let got: f64 = (0..6).map(|j| jac[i][j] * dq[j]).sum();
            assert!((got - e[i]).abs() < 1e-9);
        }
    }
}
