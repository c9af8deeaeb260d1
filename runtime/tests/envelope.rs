//! The safety envelope on its own and inside the controller: each limit, the turn fallback, the
//! sustained emergency, configuration checks and a bounded output for any finite input.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{
    EMCY_BASE_ID, HEARTBEAT_BASE_ID, NmtCommand, OBS_FRAMES, STATUS_TPDO, encode_observation,
    nmt_frame, tpdo_cob_id,
};
use dex_runtime::envelope::{
    Envelope, EnvelopeConfig, EnvelopeConfigError, status, write_arm_state,
};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, CONTROL_PERIOD_US, OBS_DIM};
use dex_runtime::kinematics::pinch_position;
use dex_runtime::testkit::{aligned_copy, jaco_policy};
use dex_runtime::{Controller, ControllerConfig, FaultCode, MockClock, State};
use embedded_can::Frame;
use proptest::prelude::*;

const T: f32 = CONTROL_PERIOD_US as f32 * 1e-6;
/// The start-state IK's nominal pose (`NOMINAL_ARM_QPOS`): hand above the workspace, pointing down.
const HOME: [f32; 6] = [0.0, 3.6, 1.3, -1.6, 1.6, 0.0];

fn envelope() -> Envelope {
    Envelope::new(EnvelopeConfig::jaco(), CONTROL_PERIOD_US)
}

fn obs(q: &[f32; 6], v: &[f32; 6]) -> [f32; OBS_DIM] {
    let mut o = [0.0; OBS_DIM];
    write_arm_state(&mut o, q, v);
    o
}

fn action(arm: [f32; 6]) -> [f32; ACT_DIM] {
    let mut a = [0.3; ACT_DIM];
    a[..6].copy_from_slice(&arm);
    a
}

#[test]
fn disabled_envelope_passes_actions_through() {
    let mut e = Envelope::new(EnvelopeConfig::disabled(), CONTROL_PERIOD_US);
    let mut a = action([0.6; 6]);
    let out = e.apply(&obs(&HOME, &[0.0; 6]), &mut a);
    assert_eq!(a, action([0.6; 6]));
    assert_eq!((out.scale, out.limits, e.status()), (1.0, 0, 0));
    assert_eq!(e.stats().cycles, 0);
}

#[test]
fn home_pose_is_inside_and_a_small_command_passes() {
    let p = pinch_position(&HOME);
    let cfg = EnvelopeConfig::jaco();
    assert!(p[2] > 0.05 && p[2] < cfg.workspace_max[2], "{p:?}");
    assert!(p[0].abs() < 0.45 && p[1].abs() < 0.45, "{p:?}");
    let mut e = envelope();
    let mut a = action([0.1, -0.1, 0.1, -0.1, 0.1, -0.1]);
    let out = e.apply(&obs(&HOME, &[0.0; 6]), &mut a);
    assert_eq!(out.scale, 1.0);
    assert_eq!(
        a,
        action([0.1, -0.1, 0.1, -0.1, 0.1, -0.1]),
        "fingers untouched too"
    );
    assert_eq!(e.status(), status::ENABLED);
}

#[test]
fn acceleration_from_rest_scales_the_whole_arm_keeping_the_direction() {
    let mut e = envelope();
    let u = [0.628, -0.314, 0.0, 0.838, 0.0, -0.419];
    let mut a = action(u);
    let out = e.apply(&obs(&HOME, &[0.0; 6]), &mut a);
    let d = 10.0 * T; // 0.5 rad/s per cycle
    assert!(out.limits & status::ACCELERATION != 0);
    let want = d / 0.838;
    assert!((out.scale - want).abs() < 1e-6, "{} vs {want}", out.scale);
    for j in 0..6 {
        assert!((a[j] - want * u[j]).abs() < 1e-6);
        assert!(a[j].abs() <= d + 1e-6);
    }
    assert_eq!(a[6..], [0.3; 3], "fingers keep their command");
}

#[test]
fn a_reversal_is_rate_limited_from_the_measured_velocity() {
    let mut e = envelope();
    let v = [0.6, 0.0, 0.0, 0.0, 0.0, 0.0];
    let mut a = action([-0.6, 0.0, 0.0, 0.0, 0.0, 0.0]);
    e.apply(&obs(&HOME, &v), &mut a);
    assert!((a[0] - (0.6 - 0.5)).abs() < 1e-5, "{}", a[0]);
    assert_eq!(e.stats().turns, 1);
}

#[test]
fn a_joint_is_stopped_before_its_limit_and_may_move_back() {
    // The joint limits alone: table and box out of reach.
    let mut cfg = EnvelopeConfig::jaco();
    cfg.table_z = -10.0;
    cfg.workspace_min = [-10.0; 3];
    cfg.workspace_max = [10.0; 3];
    let mut q = HOME;
    q[1] = cfg.joint_max[1] - 0.02;
    let mut e = Envelope::new(cfg, CONTROL_PERIOD_US);
    let v = [0.0, 0.5, 0.0, 0.0, 0.0, 0.0];
    let mut a = action([0.0, 0.6, 0.0, 0.0, 0.0, 0.0]);
    let out = e.apply(&obs(&q, &v), &mut a);
    assert!(out.limits & status::JOINT_LIMIT != 0);
    let w = a[1];
    assert!(q[1] + w * T + w * w.abs() / 20.0 <= cfg.joint_max[1] + 1e-5);
    // Beyond the limit: no further, but back is fine.
    q[1] = cfg.joint_max[1] + 0.01;
    let mut a = action([0.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
    e.apply(&obs(&q, &[0.0; 6]), &mut a);
    assert_eq!(a[1], 0.0);
    let mut a = action([0.0, -0.3, 0.0, 0.0, 0.0, 0.0]);
    let out = e.apply(&obs(&q, &[0.0, -0.3, 0.0, 0.0, 0.0, 0.0]), &mut a);
    assert_eq!((a[1], out.scale), (-0.3, 1.0));
}

#[test]
fn the_pinch_site_keeps_its_table_margin() {
    let cfg = EnvelopeConfig::jaco();
    // Lower the hand with joint 2 until the pinch site is 2 cm above the table.
    let mut q = HOME;
    let dz = |q: &[f32; 6]| pinch_position(q)[2] - 0.02;
    let (mut lo, mut hi) = (HOME[1], cfg.joint_max[1]);
    let down = dz(&[HOME[0], hi, HOME[2], HOME[3], HOME[4], HOME[5]]) < 0.0;
    assert!(down, "joint 2 towards its maximum lowers the hand");
    for _ in 0..40 {
        q[1] = 0.5 * (lo + hi);
        if dz(&q) > 0.0 { lo = q[1] } else { hi = q[1] }
    }
    let mut e = envelope();
    let mut z = pinch_position(&q)[2];
    let mut v = [0.0; 6];
    for _ in 0..40 {
        let mut a = action([0.0, 0.628, 0.0, 0.0, 0.0, 0.0]);
        e.apply(&obs(&q, &v), &mut a);
        for (qj, aj) in q.iter_mut().zip(&a) {
            *qj += aj * T;
        }
        v.copy_from_slice(&a[..6]);
        z = pinch_position(&q)[2];
        assert!(z >= cfg.table_z + cfg.table_margin - 1e-4, "pinch at {z}");
    }
    assert!(z < 0.008, "it got close ({z})");
    assert!(e.stats().table > 0);
}

#[test]
fn limiting_for_more_than_n_cycles_raises_0xff10_once_and_0x0000_when_it_ends() {
    let file = aligned_copy(&jaco_policy(&[16], 3).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut cfg = ControllerConfig::default();
    // Every action limited: a zero acceleration budget is refused, so use a tiny one.
    cfg.envelope.max_accel = [1e-3; 6];
    let n = cfg.envelope.sustained_cycles;
    let mut c = Controller::<64>::new(cfg);
    c.load_policy(&view).unwrap();
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame(&nmt_frame(NmtCommand::Start, cfg.node_id), &clock);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let emcy = |out: &[CanFrame]| -> Vec<(u16, u8)> {
        out.iter()
            .filter(|f| f.standard_id() == Some(EMCY_BASE_ID + 0x10))
            .map(|f| (u16::from_le_bytes([f.data()[0], f.data()[1]]), f.data()[3]))
            .collect()
    };
    let mut seen = Vec::new();
    let o = obs(&HOME, &[0.0; 6]);
    for step in 0..(n + 5) {
        clock.advance(u64::from(cfg.period_us));
        c.poll(&clock);
        for f in encode_observation(0x10, &o, step as u8, &mut tx) {
            let out = c.on_frame(&f, &clock);
            for e in emcy(&out) {
                seen.push((step, e));
            }
        }
    }
    assert_eq!(c.state(), State::Operational, "a warning, not a fault");
    assert_eq!(c.fault(), FaultCode::None);
    assert_eq!(seen, [(n, (0xFF10, 16))]);
    assert!(c.envelope_status() & status::SUSTAINED != 0);
    assert!(c.envelope_stats().longest > n);
    // The status TPDO, sent with the heartbeat, carries the status byte.
    clock.advance(u64::from(cfg.period_us) * 10);
    let out = c.poll(&clock);
    assert!(
        out.iter()
            .any(|f| f.standard_id() == Some(HEARTBEAT_BASE_ID + 0x10))
    );
    let status: Vec<_> = out
        .into_iter()
        .filter(|f| f.standard_id() == Some(tpdo_cob_id(0x10, STATUS_TPDO)))
        .collect();
    assert_eq!(status[0].data()[4], c.envelope_status());
}

#[test]
fn an_invalid_envelope_refuses_nmt_start() {
    let file = aligned_copy(&jaco_policy(&[16], 3).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut cfg = ControllerConfig::default();
    cfg.envelope.workspace_max[0] = -1.0;
    assert_eq!(
        cfg.envelope.validate(),
        Err(EnvelopeConfigError::Workspace { axis: 0 })
    );
    let mut c = Controller::<64>::new(cfg);
    c.load_policy(&view).unwrap();
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame(&nmt_frame(NmtCommand::Start, cfg.node_id), &clock);
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.fault(), FaultCode::EnvelopeConfig);
    let mut bad = EnvelopeConfig::jaco();
    bad.max_accel[2] = 0.0;
    assert_eq!(bad.validate(), Err(EnvelopeConfigError::NotPositive));
    bad = EnvelopeConfig::jaco();
    bad.table_z = f32::NAN;
    assert_eq!(bad.validate(), Err(EnvelopeConfigError::NonFinite));
    assert_eq!(EnvelopeConfig::jaco().validate(), Ok(()));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// Any finite state and command: the output stays within the clamps, never pushes a joint
    /// further past its limit, and the envelope is deterministic.
    #[test]
    fn any_finite_input_gives_a_bounded_deterministic_output(
        q in prop::array::uniform6(-3.2f32..6.4),
        v in prop::array::uniform6(-3.0f32..3.0),
        u in prop::array::uniform6(-1.0f32..1.0),
    ) {
        let u: [f32; 6] = core::array::from_fn(|j| u[j] * ACTION_JOINTS[j].max);
        let o = obs(&q, &v);
        let mut a = action(u);
        let mut b = action(u);
        envelope().apply(&o, &mut a);
        envelope().apply(&o, &mut b);
        prop_assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        let cfg = EnvelopeConfig::jaco();
        let (qq, _) = envelope().arm_state(&o);
        for j in 0..6 {
            prop_assert!(a[j].is_finite());
            prop_assert!(a[j] >= ACTION_JOINTS[j].min && a[j] <= ACTION_JOINTS[j].max);
            if cfg.joint_limited[j] {
                if qq[j] >= cfg.joint_max[j] { prop_assert!(a[j] <= 0.0); }
                if qq[j] <= cfg.joint_min[j] { prop_assert!(a[j] >= 0.0); }
            }
        }
    }
}

/// Found by the property below (session 26): joint 3 at 0 rad, which unwraps to 2 pi, beyond its
/// upper limit, and a command turned by the acceleration limit into a tiny positive velocity.
/// A motion below the angle's rounding must still count as a motion past the limit.
#[test]
fn a_joint_past_its_limit_is_not_pushed_further_by_a_motion_below_rounding() {
    let q = [0.0, 0.0, 0.0, -1.316_159_7, 0.0, 0.0];
    let v = [0.0, 0.0, 0.057_858_4, 0.0, 0.0, 2.835_613_7];
    let u0 = [0.0, 0.0, -0.516_425_67, 0.0, 0.0, -0.611_847_5];
    let u: [f32; 6] = core::array::from_fn(|j| u0[j] * ACTION_JOINTS[j].max);
    let o = obs(&q, &v);
    let mut a = action(u);
    envelope().apply(&o, &mut a);
    let (qq, _) = envelope().arm_state(&o);
    let cfg = EnvelopeConfig::jaco();
    assert!(qq[2] >= cfg.joint_max[2]);
    assert!(
        a[2] <= 0.0,
        "joint 3 pushed further past its limit: {}",
        a[2]
    );
}
