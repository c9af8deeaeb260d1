//! The controller in the CAN FD layout (`Controller::new_fd`): the same actions, bit for bit, as
//! the classic controller on the same observations; the same watchdog, E2E checks, NaN and
//! malformed-frame handling.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::PolicyView;
use dex_runtime::can::e2e::{E2eReceiver, E2eSender, E2eStatus};
use dex_runtime::can::fd_messages::{
    FD_OBS_FRAMES, decode_action_fd, encode_observation_fd, fd_action_frame_index,
};
use dex_runtime::can::messages::{
    EMCY_BASE_ID, NmtCommand, OBS_FRAMES, encode_observation, nmt_frame, rpdo_cob_id,
};
use dex_runtime::can::{AnyFrame, CanFrame, FdFrame, FrameLayout};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::testkit::{AlignedBytes, aligned_copy, observation_trace};
use dex_runtime::{Controller, ControllerConfig, FaultCode, MockClock, Outbox, State};
use embedded_can::Frame;

const PERIOD: u64 = 50_000;
const NODE: u8 = 0x10;

fn policy() -> AlignedBytes {
    aligned_copy(include_bytes!("golden/jaco_64.dxpl"))
}

fn operational_fd<'p>(view: &PolicyView<'p>, clock: &MockClock) -> Controller<'p, 64, AnyFrame> {
    let mut c = Controller::<64, AnyFrame>::new_fd(ControllerConfig::default());
    assert_eq!(c.layout(), FrameLayout::Fd);
    c.poll(clock);
    c.load_policy(view).unwrap();
    c.on_frame(&nmt_frame(NmtCommand::Start, NODE), clock);
    assert_eq!(c.state(), State::Operational);
    c
}

/// The FD action in `out` (checked: one 20-byte frame on TPDO 0, E2E intact), if any.
fn fd_action(out: &Outbox<AnyFrame>) -> Option<[f32; ACT_DIM]> {
    let mut found = None;
    for f in out {
        let id = f.standard_id().unwrap();
        if fd_action_frame_index(NODE, id).is_some() {
            assert!(f.is_fd(), "the action is an FD frame");
            assert_eq!(E2eReceiver::new(15).check(id, f.data()), E2eStatus::Ok);
            let mut a = [f32::NAN; ACT_DIM];
            decode_action_fd(f.data(), &mut a).unwrap();
            assert!(found.is_none(), "one action frame");
            found = Some(a);
        }
    }
    found
}

fn emcy_code(out: &Outbox<AnyFrame>) -> Option<u16> {
    out.iter()
        .find(|f| f.standard_id() == Some(EMCY_BASE_ID + u16::from(NODE)))
        .map(|f| u16::from_le_bytes([f.data()[0], f.data()[1]]))
}

struct FdPlant {
    tx: [E2eSender; FD_OBS_FRAMES],
    sample: u8,
}

impl FdPlant {
    fn frames(&mut self, obs: &[f32; OBS_DIM]) -> [FdFrame; FD_OBS_FRAMES] {
        self.sample = self.sample.wrapping_add(1);
        encode_observation_fd(NODE, obs, self.sample, &mut self.tx)
    }
}

fn fd_plant() -> FdPlant {
    FdPlant {
        tx: [E2eSender::default(); FD_OBS_FRAMES],
        sample: 0,
    }
}

fn feed(
    c: &mut Controller<'_, 64, AnyFrame>,
    clock: &MockClock,
    frames: &[FdFrame],
) -> Outbox<AnyFrame> {
    let mut last = Outbox::new();
    for f in frames {
        last = c.on_frame(f, clock);
    }
    last
}

#[test]
fn the_fd_controller_sends_the_classic_controllers_actions_bit_for_bit() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut fd = operational_fd(&view, &clock);
    let mut classic = Controller::<64>::new(ControllerConfig::default());
    classic.poll(&clock);
    classic.load_policy(&view).unwrap();
    classic.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    let mut plant = fd_plant();
    let mut classic_tx = [E2eSender::default(); OBS_FRAMES];
    for (n, obs) in observation_trace(40, 7).iter().enumerate() {
        clock.advance(PERIOD);
        fd.poll(&clock);
        classic.poll(&clock);
        let frames = plant.frames(obs);
        assert!(
            fd.on_frame(&frames[0], &clock).is_empty(),
            "no action before the last frame"
        );
        let out = fd.on_frame(&frames[1], &clock);
        assert_eq!(out[0].standard_id(), Some(0x190), "the action first");
        let sent = fd_action(&out).expect("an action");
        for f in encode_observation(NODE, obs, n as u8, &mut classic_tx) {
            classic.on_frame(&f, &clock);
        }
        assert_eq!(
            fd.last_observation().map(f32::to_bits),
            classic.last_observation().map(f32::to_bits)
        );
        assert_eq!(
            fd.last_action().map(f32::to_bits),
            classic.last_action().map(f32::to_bits)
        );
        for (s, w) in sent.iter().zip(classic.last_action()) {
            assert!(
                (s - w).abs() <= 0.0005 + 1e-6,
                "quantised to 1e-3 as classic"
            );
        }
    }
    assert_eq!(fd.diagnostics().evaluations, 40);
    assert_eq!(fd.diagnostics().e2e_errors, 0);
}

#[test]
fn malformed_and_corrupt_fd_frames_are_refused_and_counted() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational_fd(&view, &clock);
    let mut plant = fd_plant();
    let obs = observation_trace(4, 3);
    assert!(fd_action(&feed(&mut c, &clock, &plant.frames(&obs[0]))).is_some());
    let frames = plant.frames(&obs[1]);
    // Wrong lengths: the classic 8-byte frame on the same identifier, a 64-byte FD frame.
    let classic = CanFrame::standard(rpdo_cob_id(NODE, 0), &frames[0].data()[..8]).unwrap();
    assert!(c.on_frame(&classic, &clock).is_empty());
    let mut long = [0u8; 64];
    long[..48].copy_from_slice(frames[0].data());
    assert!(
        c.on_frame(
            &FdFrame::standard(rpdo_cob_id(NODE, 0), &long).unwrap(),
            &clock
        )
        .is_empty()
    );
    assert_eq!(c.diagnostics().e2e_errors, 2);
    // A corrupted frame (one bit of a value): dropped by E2E, the observation never completes.
    let mut bad = frames[1].data().to_vec();
    bad[30] ^= 0x01;
    let bad = FdFrame::standard(rpdo_cob_id(NODE, 1), &bad).unwrap();
    assert!(c.on_frame(&frames[0], &clock).is_empty());
    assert!(fd_action(&c.on_frame(&bad, &clock)).is_none());
    assert_eq!(c.diagnostics().e2e_errors, 3);
    // Repeated: dropped and counted.
    c.on_frame(&frames[0], &clock);
    assert_eq!(c.diagnostics().repeated, 1);
    // The classic layout's third RPDO is not an observation frame here.
    let third = CanFrame::standard(rpdo_cob_id(NODE, 2), &[0; 8]).unwrap();
    let ignored = c.diagnostics().ignored_frames;
    c.on_frame(&third, &clock);
    assert_eq!(c.diagnostics().ignored_frames, ignored + 1);
    // Frame 1's counter jumps by two: wrong sequence; then resynchronised.
    assert!(fd_action(&feed(&mut c, &clock, &plant.frames(&obs[2]))).is_none());
    assert_eq!(c.diagnostics().wrong_sequence, 1);
    assert!(fd_action(&feed(&mut c, &clock, &plant.frames(&obs[3]))).is_some());
    assert_eq!(c.state(), State::Operational);
}

#[test]
fn watchdog_nan_and_out_of_range_act_as_in_the_classic_layout() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational_fd(&view, &clock);
    let mut plant = fd_plant();
    let obs = observation_trace(1, 2)[0];
    clock.advance(1_000);
    assert!(fd_action(&feed(&mut c, &clock, &plant.frames(&obs))).is_some());
    let mut stopped_at = None;
    for tick in 1..=5 {
        clock.set(tick * PERIOD + 2_000);
        let out = c.poll(&clock);
        if c.state() == State::SafeStop && stopped_at.is_none() {
            stopped_at = Some(tick);
            assert_eq!(emcy_code(&out), Some(0x8250));
            assert_eq!(
                fd_action(&out),
                Some([0.0; ACT_DIM]),
                "the safe action, one FD frame"
            );
        }
    }
    assert_eq!(stopped_at, Some(3));
    assert_eq!(c.fault(), FaultCode::ObservationTimeout);
    for (index, value, fault, code) in [
        (5, f32::NAN, FaultCode::ObservationNonFinite, 0xFF02),
        (30, 3.1, FaultCode::ObservationOutOfRange, 0xFF03),
        (40, f32::INFINITY, FaultCode::ObservationNonFinite, 0xFF02),
    ] {
        let mut c = operational_fd(&view, &clock);
        let mut plant = fd_plant();
        let mut obs = [0.0f32; OBS_DIM];
        obs[index] = value;
        let out = feed(&mut c, &clock, &plant.frames(&obs));
        assert_eq!(
            (c.state(), c.fault()),
            (State::SafeStop, fault),
            "index {index}"
        );
        assert_eq!(emcy_code(&out), Some(code));
        assert_eq!(fd_action(&out), Some([0.0; ACT_DIM]));
    }
}
