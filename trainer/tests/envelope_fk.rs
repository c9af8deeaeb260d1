//! The safety envelope's kinematics (`dex_runtime::kinematics`, f32, constants generated from the
//! scene) against MuJoCo's pinch-site pose, and the generated constants against the model.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_runtime::kinematics::{JointTrig, pinch_pose, pinch_position_trig};
use dex_trainer::env::Scene;
use dex_trainer::env::fk_constants::runtime_constants;
use dex_trainer::env::rng::SeedRng;

const GENERATED: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../runtime/src/jaco_kinematics.rs"
);

#[test]
fn generated_constants_match_the_model() {
    let scene = Scene::load().unwrap();
    let fresh = runtime_constants(&scene).unwrap();
    if std::env::var_os("DEX_BLESS").is_some() {
        std::fs::write(GENERATED, &fresh).unwrap();
    }
    let committed = std::fs::read_to_string(GENERATED).unwrap();
    assert!(
        committed == fresh,
        "runtime/src/jaco_kinematics.rs differs from the model: rerun with DEX_BLESS=1"
    );
}

#[test]
fn f32_pinch_pose_matches_mujoco_over_1000_configurations() {
    let scene = Scene::load().unwrap();
    let ids = *scene.ids();
    let mut data = scene.make_data();
    let (limited, ranges) = (
        dex_runtime::jaco_kinematics::JOINT_LIMITED,
        dex_runtime::jaco_kinematics::JOINT_RANGE,
    );
    let mut rng = SeedRng::new(17);
    let (mut worst_pos, mut worst_rot, mut worst_trig) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..1000 {
        let mut q = [0.0f64; 6];
        for (j, x) in q.iter_mut().enumerate() {
            *x = if limited[j] {
                rng.uniform(f64::from(ranges[j][0]), f64::from(ranges[j][1]))
            } else {
                rng.uniform(-std::f64::consts::PI, std::f64::consts::PI)
            };
            data.qpos_mut()[ids.joint_qpos[j]] = *x;
        }
        data.kinematics();
        let want_pos = data.site_xpos()[ids.pinch_site];
        let m = data.site_xmat()[ids.pinch_site];
        let got = pinch_pose(&q.map(|x| x as f32));
        let dp = (0..3)
            .map(|i| (f64::from(got.pos[i]) - want_pos[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        // The envelope's position-only chain (matrices on each joint's sine and cosine).
        let trig = pinch_position_trig(&JointTrig::of(&q.map(|x| x as f32)));
        worst_trig = worst_trig.max(
            (0..3)
                .map(|i| (f64::from(trig[i]) - want_pos[i]).powi(2))
                .sum::<f64>()
                .sqrt(),
        );
        // Rotation error: the angle of M = R_got^T R_want, from its skew part and its trace
        // (atan2 of both: accurate near zero, where acos of the trace alone is not).
        let r = got.rot.to_rotation_matrix();
        let mm = |a: usize, b: usize| -> f64 {
            (0..3).map(|k| f64::from(r[(k, a)]) * m[3 * k + b]).sum()
        };
        let w = [
            mm(2, 1) - mm(1, 2),
            mm(0, 2) - mm(2, 0),
            mm(1, 0) - mm(0, 1),
        ];
        let sin = 0.5 * w.iter().map(|x| x * x).sum::<f64>().sqrt();
        let cos = 0.5 * (mm(0, 0) + mm(1, 1) + mm(2, 2) - 1.0);
        let angle = sin.atan2(cos);
        worst_pos = worst_pos.max(dp);
        worst_rot = worst_rot.max(angle);
    }
    println!(
        "worst over 1000: position {worst_pos:.2e} m, orientation {worst_rot:.2e} rad, \
         the envelope's position {worst_trig:.2e} m"
    );
    assert!(worst_pos < 1e-3, "position error {worst_pos} m");
    assert!(
        worst_trig < 1e-3,
        "the envelope's position error {worst_trig} m"
    );
    assert!(worst_rot < 1e-2, "orientation error {worst_rot} rad");
}
