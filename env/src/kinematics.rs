//! Pinch-site kinematics for the arm: pose, 6x6 Jacobian, orientation error and damped least squares,
//! with `nalgebra` (`Matrix6`, a Cholesky solve, `Rotation3`, `Vector3`/`Vector6`).
//!
//! Used by the start-state sampler (place the hand at a random pose by inverse kinematics) and by the
//! scripted demonstrator (resolved-rate control of the pinch site).

use std::sync::Arc;

use mujoco_rs::prelude::*;
use nalgebra::{Matrix3, Matrix6, Rotation3, Vector3, Vector6};

use super::scene::{ARM_JOINTS, SceneIds};

/// The pinch site's position and orientation (after kinematics).
pub fn pinch_pose(data: &MjData<Arc<MjModel>>, ids: &SceneIds) -> (Vector3<f64>, Rotation3<f64>) {
    let pos = data
        .site_xpos()
        .get(ids.pinch_site)
        .copied()
        .unwrap_or([0.0; 3]);
    let mat = data
        .site_xmat()
        .get(ids.pinch_site)
        .copied()
        .unwrap_or([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    // MuJoCo's xmat is row-major; MuJoCo keeps it orthonormal.
    let m = Matrix3::from_row_slice(&mat);
    (Vector3::from(pos), Rotation3::from_matrix_unchecked(m))
}

/// Rotation of a pinch site that points straight down with its closing axis (site x) at `yaw`:
/// a turn by pi about x (z down), then `yaw` about the world's z.
pub fn down_rotation(yaw: f64) -> Rotation3<f64> {
    let (s, c) = yaw.sin_cos();
    // Rz(yaw) Rx(pi), written out (exact zeros and ones).
    Rotation3::from_matrix_unchecked(Matrix3::new(c, s, 0.0, s, -c, 0.0, 0.0, 0.0, -1.0))
}

/// Rotation vector (axis times angle, small-angle form: half the sum of the column cross
/// products) that turns `current` towards `target`.
pub fn orientation_error(current: &Rotation3<f64>, target: &Rotation3<f64>) -> Vector3<f64> {
    let (r, t) = (current.matrix(), target.matrix());
    (0..3).fold(Vector3::zeros(), |e, col| {
        e + 0.5 * r.column(col).cross(&t.column(col))
    })
}

/// The pinch site's 6x6 Jacobian over the arm joints: rows 0-2 linear, 3-5 angular velocity.
pub fn arm_jacobian(data: &MjData<Arc<MjModel>>, ids: &SceneIds) -> Matrix6<f64> {
    let nv = data.model().ffi().nv as usize;
    let mut jac = Matrix6::zeros();
    let Ok((jacp, jacr)) = data.try_jac_site(true, true, ids.pinch_site) else {
        return jac;
    };
    for (j, &dof) in ids.joint_dof[..ARM_JOINTS].iter().enumerate() {
        for r in 0..3 {
            jac[(r, j)] = jacp.get(r * nv + dof).copied().unwrap_or(0.0);
            jac[(3 + r, j)] = jacr.get(r * nv + dof).copied().unwrap_or(0.0);
        }
    }
    jac
}

/// Damped least squares: `J^T (J J^T + lambda^2 I)^-1 e`, the joint step that best achieves `e`
/// (Cholesky: the matrix is symmetric positive definite for `lambda > 0`; zero if it is not).
pub fn damped_least_squares(jac: &Matrix6<f64>, e: &Vector6<f64>, lambda: f64) -> Vector6<f64> {
    let a = jac * jac.transpose() + Matrix6::identity() * (lambda * lambda);
    match a.cholesky() {
        Some(c) => jac.transpose() * c.solve(e),
        None => Vector6::zeros(),
    }
}

/// Pose error of the pinch site: (target position - position, orientation error).
pub fn pose_error(
    data: &MjData<Arc<MjModel>>,
    ids: &SceneIds,
    pos: &Vector3<f64>,
    rot: &Rotation3<f64>,
) -> Vector6<f64> {
    let (p, m) = pinch_pose(data, ids);
    let d = pos - p;
    let o = orientation_error(&m, rot);
    Vector6::new(d[0], d[1], d[2], o[0], o[1], o[2])
}

/// Moves the arm joints (positions only) until the pinch site reaches `pos` with orientation `rot`.
/// Returns the final position error norm in metres and orientation error norm in radians.
/// Joint limits are respected by clamping. Leaves kinematics (not dynamics) up to date.
pub fn solve_ik(
    data: &mut MjData<Arc<MjModel>>,
    ids: &SceneIds,
    pos: &Vector3<f64>,
    rot: &Rotation3<f64>,
    iterations: usize,
) -> (f64, f64) {
    let (limited, ranges) = joint_ranges(data.model(), ids);
    for _ in 0..iterations {
        data.kinematics();
        data.com_pos();
        let err = pose_error(data, ids, pos, rot);
        if linear(&err).norm() < 1e-4 && angular(&err).norm() < 1e-3 {
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
    (linear(&err).norm(), angular(&err).norm())
}

/// A MuJoCo row-major orientation matrix (`xmat`) as a rotation.
pub fn xmat_rotation(m: &[f64; 9]) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(m))
}

/// The linear (first three) part of a twist or pose error.
pub fn linear(v: &Vector6<f64>) -> Vector3<f64> {
    v.fixed_rows::<3>(0).into_owned()
}

/// The angular (last three) part of a twist or pose error.
pub fn angular(v: &Vector6<f64>) -> Vector3<f64> {
    v.fixed_rows::<3>(3).into_owned()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn down_rotation_is_proper_and_points_down() {
        let m = down_rotation(0.7);
        assert!((m[(2, 2)] + 1.0).abs() < 1e-12, "site z axis is -z");
        assert!((m.matrix().determinant() - 1.0).abs() < 1e-12);
        // Closing axis (site x) at the yaw.
        assert!((m[(1, 0)].atan2(m[(0, 0)]) - 0.7).abs() < 1e-12);
        assert_eq!(orientation_error(&m, &m), Vector3::zeros());
        // A small yaw difference shows up as a rotation about z.
        let e = orientation_error(&down_rotation(0.0), &down_rotation(0.01));
        assert!(e[0].abs() < 1e-12 && e[1].abs() < 1e-12 && (e[2] - 0.01f64.sin()).abs() < 1e-9);
    }

    #[test]
    fn dls_inverts_a_well_conditioned_jacobian() {
        let mut jac = Matrix6::zeros();
        for i in 0..6 {
            jac[(i, i)] = 2.0;
            jac[(i, (i + 1) % 6)] = 0.5;
        }
        let e = Vector6::new(0.1, -0.2, 0.3, 0.0, 0.05, -0.1);
        let dq = damped_least_squares(&jac, &e, 1e-6);
        assert!((jac * dq - e).amax() < 1e-9);
    }
}
