//! The controller's state machine, watchdog, fault handling and end-to-end checks, driven by a mock
//! clock and frames built with the plant-side codec.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::{E2eLayout, E2eReceiver, E2eSender, E2eStatus};
use dex_runtime::can::messages::{
    ACTION_FRAMES, EMCY_BASE_ID, HEARTBEAT_BASE_ID, NmtCommand, OBS_FRAMES, POLICY_INFO_TPDO,
    STATUS_TPDO, action_frame_index, decode_action_frame, encode_observation, nmt_frame,
    quantise_observation, tpdo_cob_id,
};
use dex_runtime::envelope::{Envelope, EnvelopeConfig};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::testkit::{AlignedBytes, aligned_copy, jaco_policy, observation_trace};
use dex_runtime::{
    Controller, ControllerConfig, FaultCode, LoadError, Mlp, MockClock, Outbox, State,
};
use embedded_can::Frame;

const PERIOD: u64 = 50_000;
const NODE: u8 = 0x10;

fn policy() -> AlignedBytes {
    aligned_copy(include_bytes!("golden/jaco_64.dxpl"))
}

struct Plant {
    tx: [E2eSender; OBS_FRAMES],
    sample: u8,
}

impl Plant {
    fn new() -> Self {
        Plant {
            tx: [E2eSender::default(); OBS_FRAMES],
            sample: 0,
        }
    }
    fn frames(&mut self, obs: &[f32; OBS_DIM]) -> [CanFrame; OBS_FRAMES] {
        self.sample = self.sample.wrapping_add(1);
        encode_observation(NODE, obs, self.sample, &mut self.tx)
    }
}

fn ids(out: &Outbox) -> Vec<u16> {
    out.iter().map(|f| f.standard_id().unwrap()).collect()
}

fn emcy_code(out: &Outbox) -> Option<u16> {
    out.iter()
        .find(|f| f.standard_id() == Some(EMCY_BASE_ID + u16::from(NODE)))
        .map(|f| u16::from_le_bytes([f.data()[0], f.data()[1]]))
}

fn actions(out: &Outbox) -> Option<[f32; ACT_DIM]> {
    let mut action = [f32::NAN; ACT_DIM];
    let mut seen = 0;
    for f in out.iter() {
        let id = f.standard_id().unwrap();
        if let Some(k) = action_frame_index(NODE, id) {
            let mut rx = E2eReceiver::new(15);
            assert_eq!(
                rx.check(id, f.data()),
                E2eStatus::Ok,
                "action frame protected"
            );
            decode_action_frame(k, f.data(), &mut action).unwrap();
            seen += 1;
        }
    }
    (seen == ACTION_FRAMES).then_some(action)
}

/// Feeds a whole observation; returns what the controller sent in response to the last frame.
fn feed(c: &mut Controller<'_, 64>, clock: &MockClock, frames: &[CanFrame]) -> Outbox {
    let mut last = Outbox::new();
    for f in frames {
        last = c.on_frame(f, clock);
    }
    last
}

fn operational<'p>(view: &PolicyView<'p>, clock: &MockClock) -> Controller<'p, 64> {
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(clock);
    c.load_policy(view).unwrap();
    c.on_frame(&nmt_frame(NmtCommand::Start, NODE), clock);
    assert_eq!(c.state(), State::Operational);
    c
}

#[test]
fn boots_to_preoperational_with_boot_up_heartbeat_and_policy_info() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = Controller::<64>::new(ControllerConfig::default());
    assert_eq!(c.state(), State::Boot);
    let out = c.poll(&clock);
    assert_eq!(c.state(), State::PreOperational);
    let hb: Vec<&CanFrame> = out
        .iter()
        .filter(|f| f.standard_id() == Some(HEARTBEAT_BASE_ID + u16::from(NODE)))
        .collect();
    assert_eq!(hb.len(), 2);
    assert_eq!(hb[0].data()[0], 0x00, "boot-up");
    assert_eq!(hb[1].data()[0], 0x7F, "pre-operational");
    c.load_policy(&view).unwrap();
    clock.advance(PERIOD);
    let out = c.poll(&clock);
    let info = out
        .iter()
        .find(|f| f.standard_id() == Some(tpdo_cob_id(NODE, POLICY_INFO_TPDO)))
        .expect("policy info after load");
    assert_eq!(
        u32::from_le_bytes(info.data()[2..6].try_into().unwrap()),
        view.header().layout_hash
    );
    assert!(
        actions(&out).unwrap().iter().all(|a| *a == 0.0),
        "safe action in pre-op"
    );
}

#[test]
fn start_without_policy_is_refused_with_an_emergency() {
    let clock = MockClock::new(0);
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(&clock);
    let out = c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.fault(), FaultCode::NoPolicy);
    assert_eq!(emcy_code(&out), Some(0xFF05));
}

#[test]
fn operational_evaluates_every_complete_observation_exactly_like_the_evaluator() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut reference = Mlp::<64>::new(&view).unwrap();
    // The controller's action is the evaluator's behind the safety envelope.
    let mut envelope = Envelope::new(EnvelopeConfig::jaco(), PERIOD as u32);
    let mut c = operational(&view, &clock);
    let mut plant = Plant::new();
    for obs in observation_trace(30, 1) {
        clock.advance(PERIOD);
        c.poll(&clock);
        let frames = plant.frames(&obs);
        for f in &frames[..OBS_FRAMES - 1] {
            assert!(
                c.on_frame(f, &clock).is_empty(),
                "no action before the last frame"
            );
        }
        let out = c.on_frame(&frames[OBS_FRAMES - 1], &clock);
        // The action frames, then at most the envelope's emergency (random observations put
        // the arm anywhere, so it limits).
        assert_eq!(ids(&out)[..3], [0x190, 0x290, 0x390]);
        assert!(
            ids(&out)[3..]
                .iter()
                .all(|&id| id == EMCY_BASE_ID + u16::from(NODE))
        );
        let sent = actions(&out).unwrap();
        let quantised: [f32; OBS_DIM] = core::array::from_fn(|i| quantise_observation(i, obs[i]));
        let mut want = [0.0; ACT_DIM];
        reference.act(&quantised, &mut want).unwrap();
        envelope.apply(&quantised, &mut want);
        assert_eq!(c.last_action().map(f32::to_bits), want.map(f32::to_bits));
        for (s, w) in sent.iter().zip(want) {
            assert!((s - w).abs() <= 0.0005 + 1e-6, "action quantised to 1e-3");
        }
    }
    assert_eq!(c.diagnostics().evaluations, 30);
    assert_eq!(c.diagnostics().e2e_errors, 0);
}

#[test]
fn watchdog_safe_stops_within_three_cycles_and_sends_zero_velocity() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    let mut plant = Plant::new();
    let obs = observation_trace(1, 2)[0];
    clock.advance(1_000);
    assert!(actions(&feed(&mut c, &clock, &plant.frames(&obs))).is_some());
    let mut stopped_at = None;
    for tick in 1..=5 {
        clock.set(tick * PERIOD + 2_000);
        let out = c.poll(&clock);
        if c.state() == State::SafeStop && stopped_at.is_none() {
            stopped_at = Some(tick);
            assert_eq!(emcy_code(&out), Some(0x8250));
            assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
        }
    }
    assert_eq!(
        stopped_at,
        Some(3),
        "150 ms watchdog = third cycle without observation"
    );
    assert_eq!(c.fault(), FaultCode::ObservationTimeout);
    // Observations while safe-stopped are not evaluated.
    let out = feed(&mut c, &clock, &plant.frames(&obs));
    assert!(actions(&out).is_none());
    // NMT start recovers and reports the error reset.
    let out = c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    assert_eq!(c.state(), State::Operational);
    assert_eq!(emcy_code(&out), Some(0x0000));
}

#[test]
fn non_finite_and_out_of_range_observations_fault() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    for (index, value, fault, code) in [
        (5, f32::NAN, FaultCode::ObservationNonFinite, 0xFF02),
        (20, f32::INFINITY, FaultCode::ObservationNonFinite, 0xFF02),
        (30, 3.1, FaultCode::ObservationOutOfRange, 0xFF03),
        (0, 1.9, FaultCode::ObservationOutOfRange, 0xFF03),
    ] {
        let mut c = operational(&view, &clock);
        let mut plant = Plant::new();
        let mut obs = [0.0f32; OBS_DIM];
        obs[index] = value;
        let out = feed(&mut c, &clock, &plant.frames(&obs));
        assert_eq!(c.state(), State::SafeStop, "index {index}");
        assert_eq!(c.fault(), fault);
        assert_eq!(emcy_code(&out), Some(code));
        assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    }
}

#[test]
fn corrupted_repeated_and_skipped_frames_are_dropped_and_counted() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    let mut plant = Plant::new();
    let obs = observation_trace(4, 4);
    assert!(actions(&feed(&mut c, &clock, &plant.frames(&obs[0]))).is_some());
    let frames = plant.frames(&obs[1]);
    // A corrupted frame 4: dropped, so this observation never completes.
    let mut bad = frames[4].data().to_vec();
    bad[3] ^= 0x01;
    let bad = CanFrame::standard(frames[4].standard_id().unwrap(), &bad).unwrap();
    for (k, f) in frames.iter().enumerate() {
        let out = c.on_frame(if k == 4 { &bad } else { f }, &clock);
        assert!(actions(&out).is_none());
    }
    assert_eq!(c.diagnostics().e2e_errors, 1);
    // The same frame again: repeated.
    c.on_frame(&frames[0], &clock);
    assert_eq!(c.diagnostics().repeated, 1);
    // Frame 4's alive counter now jumps by two (one frame lost): wrong sequence with max delta 1.
    let out = feed(&mut c, &clock, &plant.frames(&obs[2]));
    assert!(actions(&out).is_none());
    assert_eq!(c.diagnostics().wrong_sequence, 1);
    // Resynchronised: the next sample completes, and only its own values are used.
    let out = feed(&mut c, &clock, &plant.frames(&obs[3]));
    assert!(actions(&out).is_some());
    assert_eq!(c.diagnostics().incomplete_observations, 2);
    let quantised: [f32; OBS_DIM] = core::array::from_fn(|i| quantise_observation(i, obs[3][i]));
    assert_eq!(c.last_observation(), &quantised);
}

#[test]
fn policies_load_only_outside_operational_and_must_match_the_layout() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    assert_eq!(c.load_policy(&view), Err(LoadError::Operational));
    c.on_frame(&nmt_frame(NmtCommand::EnterPreOperational, NODE), &clock);
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.load_policy(&view), Ok(()));

    let golden = aligned_copy(include_bytes!(
        "../../policy-format/tests/golden/small.dxpl"
    ));
    let other = PolicyView::decode(golden.as_bytes()).unwrap();
    let before = c.policy_info();
    assert!(matches!(
        c.load_policy(&other),
        Err(LoadError::Format(
            dex_policy::FormatError::ObservationLayoutMismatch { field: 0 }
        ))
    ));
    assert_eq!(c.policy_info(), before, "old policy stays active");
    assert_eq!(c.state(), State::PreOperational);

    let wide = aligned_copy(&jaco_policy(&[128], 1).unwrap());
    let wide = PolicyView::decode(wide.as_bytes()).unwrap();
    assert!(matches!(
        c.load_policy(&wide),
        Err(LoadError::Format(
            dex_policy::FormatError::ExceedsCapacity { .. }
        ))
    ));
}

#[test]
fn nmt_addressing_stop_and_reset() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    c.on_frame(&nmt_frame(NmtCommand::Stop, 0x22), &clock);
    assert_eq!(
        c.state(),
        State::Operational,
        "other node's command ignored"
    );
    let out = c.on_frame(&nmt_frame(NmtCommand::Stop, 0), &clock);
    assert_eq!(c.state(), State::SafeStop, "broadcast applies");
    assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    c.on_frame(&nmt_frame(NmtCommand::ResetNode, NODE), &clock);
    assert_eq!(c.state(), State::Boot);
    clock.advance(PERIOD);
    c.poll(&clock);
    assert_eq!(c.state(), State::PreOperational);
    assert!(c.policy_info().is_some(), "policy survives a node reset");
    // Garbage on the NMT id and unknown ids are ignored.
    c.on_frame(&CanFrame::standard(0, &[0x55]).unwrap(), &clock);
    c.on_frame(&CanFrame::standard(0x123, &[1, 2, 3]).unwrap(), &clock);
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.diagnostics().ignored_frames, 2);
}

#[test]
fn heartbeat_period_and_missed_cycles() {
    let clock = MockClock::new(0);
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(&clock);
    let mut heartbeats = Vec::new();
    for tick in 1..=40u64 {
        clock.set(tick * PERIOD);
        let out = c.poll(&clock);
        if out
            .iter()
            .any(|f| f.standard_id() == Some(HEARTBEAT_BASE_ID + u16::from(NODE)))
        {
            heartbeats.push(tick);
        }
    }
    assert_eq!(heartbeats, [10, 20, 30, 40]);
    clock.set(45 * PERIOD + 10);
    c.poll(&clock);
    assert_eq!(c.diagnostics().missed_cycles, 4);
    assert_eq!(c.diagnostics().cycles, 41);
}

/// Found by `fuzz/fuzz_targets/controller_structured.rs`: with a heartbeat every cycle, the cycle
/// whose watchdog safe-stopped sent the state-change heartbeat and then the scheduled one, more
/// frames than the `Outbox` promises (past its capacity frames are lost silently).
#[test]
fn a_cycle_sends_one_heartbeat_even_with_a_heartbeat_every_cycle() {
    for heartbeat_cycles in [1] {
        let clock = MockClock::new(0);
        let file = policy();
        let view = PolicyView::decode(file.as_bytes()).unwrap();
        let mut c = Controller::<64>::new(ControllerConfig {
            heartbeat_cycles,
            ..ControllerConfig::default()
        });
        c.poll(&clock);
        c.load_policy(&view).unwrap();
        // Every cycle has its heartbeat.
        for tick in 1..=3u64 {
            clock.set(tick * PERIOD);
            let out = c.poll(&clock);
            assert_eq!(heartbeat(&out).map(|h| h[2]), Some(1), "cycle {tick}");
        }
        c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
        assert_eq!(c.state(), State::Operational);
        clock.set(8 * PERIOD);
        let out = c.poll(&clock);
        assert_eq!(c.state(), State::SafeStop);
        assert_eq!(emcy_code(&out), Some(0x8250));
        let beats = out
            .iter()
            .filter(|f| f.standard_id() == Some(HEARTBEAT_BASE_ID + u16::from(NODE)))
            .count();
        assert_eq!(
            beats,
            1,
            "heartbeat_cycles {heartbeat_cycles}: {:?}",
            ids(&out)
        );
        assert!(out.len() <= 7, "{} frames", out.len());
        // The next cycle has its heartbeat again.
        clock.set(9 * PERIOD);
        assert_eq!(heartbeat(&c.poll(&clock)).map(|h| h[2]), Some(3));
    }
}

fn emcy(out: &Outbox) -> Vec<&CanFrame> {
    out.iter()
        .filter(|f| f.standard_id() == Some(EMCY_BASE_ID + u16::from(NODE)))
        .collect()
}

/// The heartbeat's NMT state byte with the status TPDO sent beside it, as
/// `[nmt state, 0, controller state, fault code, envelope status]`.
fn heartbeat(out: &Outbox) -> Option<[u8; 5]> {
    let hb = out
        .iter()
        .find(|f| f.standard_id() == Some(HEARTBEAT_BASE_ID + u16::from(NODE)))?;
    assert_eq!(hb.data().len(), 1, "CiA 301 heartbeat: one byte");
    let status = out
        .iter()
        .find(|f| f.standard_id() == Some(tpdo_cob_id(NODE, STATUS_TPDO)))
        .expect("the status TPDO goes out with the heartbeat");
    let s = status.data();
    assert_eq!(
        E2eReceiver::new(15).check(tpdo_cob_id(NODE, STATUS_TPDO), s),
        E2eStatus::Ok
    );
    Some([hb.data()[0], 0, s[2], s[3], s[4]])
}

#[test]
fn a_write_to_0x1017_sets_the_heartbeat_period_and_zero_turns_it_off() {
    use dex_runtime::slots::PolicySlots;
    let clock = MockClock::new(0);
    let (mut ra, mut rb) = common::regions();
    let mut slots = PolicySlots::mount(common::bytes(&mut ra), common::bytes(&mut rb)).unwrap();
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll_slots(&clock, &mut slots);
    let sdo = |c: &mut Controller<'_, 64>, slots: &mut PolicySlots<'_>, d: &[u8]| {
        let req = CanFrame::standard(0x600 + u16::from(NODE), d).unwrap();
        let out = c.on_frame_slots(&req, &clock, slots);
        out[0].data().to_vec()
    };
    // 0x1017 = 150 ms: a heartbeat every 3 periods.
    let r = sdo(&mut c, &mut slots, &[0x2B, 0x17, 0x10, 0, 150, 0, 0, 0]);
    assert_eq!(r[0], 0x60);
    let r = sdo(&mut c, &mut slots, &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(r[..6], [0x4B, 0x17, 0x10, 0, 150, 0]);
    let mut beats = Vec::new();
    for tick in 1..=9u64 {
        clock.set(tick * PERIOD);
        if heartbeat(&c.poll_slots(&clock, &mut slots)).is_some() {
            beats.push(tick);
        }
    }
    assert_eq!(beats, [3, 6, 9]);
    // 0: no heartbeat, but the status TPDO still goes out on a state change.
    sdo(&mut c, &mut slots, &[0x2B, 0x17, 0x10, 0, 0, 0, 0, 0]);
    for tick in 10..=30u64 {
        clock.set(tick * PERIOD);
        assert!(heartbeat(&c.poll_slots(&clock, &mut slots)).is_none());
    }
    let out = c.on_frame_slots(&nmt_frame(NmtCommand::Stop, NODE), &clock, &mut slots);
    assert!(heartbeat(&out).is_none());
    assert!(ids(&out).contains(&tpdo_cob_id(NODE, STATUS_TPDO)));
}

#[test]
fn bus_off_in_operational_sends_the_safe_action_then_emcy_8140_and_stays_preoperational() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    let mut plant = Plant::new();
    let trace = observation_trace(6, 5);
    clock.advance(1_000);
    assert!(actions(&feed(&mut c, &clock, &plant.frames(&trace[0]))).is_some());
    // Half an observation, then bus-off: pre-operational at once, the safe action, no emergency
    // (it could not get out), the fault latched.
    for f in &plant.frames(&trace[1])[..7] {
        c.on_frame(f, &clock);
    }
    let out = c.on_bus_off();
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.fault(), FaultCode::BusOff);
    assert!(c.is_bus_off());
    assert!(emcy(&out).is_empty());
    let hb = heartbeat(&out).unwrap();
    assert_eq!(
        (hb[0], hb[2], hb[3]),
        (0x7F, 1, 6),
        "pre-operational, bus-off"
    );
    assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    assert_eq!(c.diagnostics().bus_off_events, 1);
    // While off: a second report changes nothing, every cycle sends the safe action, complete
    // observations are not evaluated, NMT start is refused.
    assert!(c.on_bus_off().is_empty());
    assert_eq!(c.diagnostics().bus_off_events, 1);
    for obs in &trace[2..4] {
        clock.advance(PERIOD);
        assert_eq!(actions(&c.poll(&clock)).unwrap(), [0.0; ACT_DIM]);
        assert!(actions(&feed(&mut c, &clock, &plant.frames(obs))).is_none());
    }
    assert!(
        c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock)
            .is_empty()
    );
    assert_eq!(c.state(), State::PreOperational);
    // Recovery: EMCY 0x8140 once (fault code 6, state pre-operational), protected like every
    // emergency; the heartbeat with the state; the safe action.
    let out = c.on_bus_recovered();
    assert!(!c.is_bus_off());
    assert_eq!(ids(&out), [0x090, 0x710, 0x1B0, 0x190, 0x290, 0x390]);
    let e = emcy(&out)[0].data();
    assert_eq!(e.len(), 8);
    // CiA 301: error code, error register (generic + communication), then fault code 6 and
    // state 1, a zero, the alive counter and the CRC.
    assert_eq!(&e[..6], &[0x40, 0x81, 0x11, 6, 1, 0]);
    let mut rx = E2eReceiver::new(1);
    assert_eq!(
        rx.check_in(E2eLayout::Tail, EMCY_BASE_ID + u16::from(NODE), e),
        E2eStatus::Ok
    );
    assert_eq!(heartbeat(&out).unwrap()[0], 0x7F);
    assert_eq!(heartbeat(&out).unwrap()[2..4], [1, 6]);
    assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    assert!(
        c.on_bus_recovered().is_empty(),
        "the emergency goes out once"
    );
    clock.advance(PERIOD);
    assert!(emcy(&c.poll(&clock)).is_empty());
    assert_eq!(c.state(), State::PreOperational);
    // The master re-enables it: error reset, operational, and the first observation after the
    // bus-off is accepted (the end-to-end counters were resynchronised).
    let out = c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    assert_eq!(emcy_code(&out), Some(0x0000));
    assert_eq!(c.state(), State::Operational);
    assert_eq!(c.fault(), FaultCode::None);
    let wrong_sequence = c.diagnostics().wrong_sequence;
    assert!(actions(&feed(&mut c, &clock, &plant.frames(&trace[5]))).is_some());
    assert_eq!(c.diagnostics().wrong_sequence, wrong_sequence);
}

#[test]
fn bus_off_keeps_safe_stop_and_its_first_fault() {
    let clock = MockClock::new(0);
    let file = policy();
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = operational(&view, &clock);
    for tick in 1..=4 {
        clock.set(tick * PERIOD + 1_000);
        c.poll(&clock);
    }
    assert_eq!(
        (c.state(), c.fault()),
        (State::SafeStop, FaultCode::ObservationTimeout)
    );
    let out = c.on_bus_off();
    assert_eq!(
        (c.state(), c.fault()),
        (State::SafeStop, FaultCode::ObservationTimeout)
    );
    assert!(heartbeat(&out).is_none(), "no state change");
    assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    let out = c.on_bus_recovered();
    let e = emcy(&out)[0].data();
    assert_eq!(
        &e[..5],
        &[0x40, 0x81, 0x11, 6, 3],
        "0x8140, bus-off, safe-stop"
    );
    assert_eq!(heartbeat(&out).unwrap()[0], 0x04);
    assert_eq!(
        heartbeat(&out).unwrap()[3],
        1,
        "the first fault stays latched"
    );
}

#[test]
fn recovery_without_bus_off_and_bus_off_in_pre_operational() {
    let clock = MockClock::new(0);
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(&clock);
    assert!(c.on_bus_recovered().is_empty(), "nothing to recover from");
    let out = c.on_bus_off();
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(c.fault(), FaultCode::BusOff);
    assert_eq!(actions(&out).unwrap(), [0.0; ACT_DIM]);
    let out = c.on_bus_recovered();
    assert_eq!(emcy_code(&out), Some(0x8140));
    assert_eq!(c.state(), State::PreOperational);
    assert_eq!(FaultCode::BusOff.code(), 6);
    assert_eq!(FaultCode::BusOff.emcy_code(), 0x8140);
}
