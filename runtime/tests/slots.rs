//! A/B policy slots behind the controller's SDO server (program download, CiA 302-3): transfer
//! into the inactive slot, verification, activation outside operational, explicit and automatic
//! roll-back, SDO timeouts, and power cuts at every byte of a transfer and of the commit.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;
use common::{REGION, bytes, regions};

use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{
    ACTION_FRAMES, EMCY_BASE_ID, NmtCommand, OBS_FRAMES, action_frame_index, encode_observation,
    nmt_frame,
};
use dex_runtime::canopen::program::{
    FLASH_STATUS, FlashResult, PROGRAM_CONTROL, PROGRAM_DATA, PROGRAM_ID, control,
};
use dex_runtime::controller::SDO_RESPONSE_BASE;
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::slots::{CRC32, SLOT_HEADER_BYTES};
use dex_runtime::testkit::{
    aligned_copy, jaco_policy, jaco_policy_faulting, jaco_policy_int8, observation_trace,
    sdo_abort_code, sdo_block_download, sdo_read, sdo_write,
};
use dex_runtime::{
    Controller, ControllerConfig, FaultCode, Mlp, MockClock, Outbox, PolicySlots, SlotError, State,
};
use embedded_can::Frame;

const NODE: u8 = 0x10;

type Ctl = Controller<'static, 64>;

/// Responses on 0x580 + node, as byte vectors.
fn responses(out: &Outbox) -> Vec<Vec<u8>> {
    out.iter()
        .filter(|f| f.standard_id() == Some(SDO_RESPONSE_BASE + u16::from(NODE)))
        .map(|f| f.data().to_vec())
        .collect()
}

/// Feeds frames at time 0; returns every SDO response.
fn feed(c: &mut Ctl, slots: &mut PolicySlots<'_>, frames: &[CanFrame]) -> Vec<Vec<u8>> {
    let clock = MockClock::new(0);
    frames
        .iter()
        .flat_map(|f| responses(&c.on_frame_slots(f, &clock, slots)))
        .collect()
}

/// Writes program control (0x1F51:1); `None` when accepted, else the abort code.
fn command(c: &mut Ctl, slots: &mut PolicySlots<'_>, value: u8) -> Option<u32> {
    let r = feed(
        c,
        slots,
        &[sdo_write(NODE, PROGRAM_CONTROL, 1, &[value]).unwrap()],
    );
    assert_eq!(r.len(), 1);
    match sdo_abort_code(&r[0]) {
        Some(code) => Some(code),
        None => {
            assert_eq!(r[0][..4], [0x60, 0x51, 0x1F, 1]);
            None
        }
    }
}

/// Reads a u32 object (expedited upload).
fn read_u32(c: &mut Ctl, slots: &mut PolicySlots<'_>, index: u16) -> u32 {
    let r = feed(c, slots, &[sdo_read(NODE, index, 1).unwrap()]);
    assert_eq!(r.len(), 1);
    assert_eq!(r[0][0], 0x43, "upload of {index:#06x}: {:02x?}", r[0]);
    u32::from_le_bytes([r[0][4], r[0][5], r[0][6], r[0][7]])
}

/// Flash status (0x1F57:1): (staged, last result).
fn flash_status(c: &mut Ctl, slots: &mut PolicySlots<'_>) -> (bool, u32) {
    let w = read_u32(c, slots, FLASH_STATUS);
    (w & 0x100 != 0, (w >> 1) & 0x7F)
}

/// An abort request from the client (code 0x0800_0000).
fn client_abort(index: u16, sub: u8) -> CanFrame {
    let i = index.to_le_bytes();
    CanFrame::standard(
        0x600 + u16::from(NODE),
        &[0x80, i[0], i[1], sub, 0, 0, 0, 8],
    )
    .unwrap()
}

/// Block-downloads `image` into 0x1F50:1; `None` when verified, else the abort code.
fn transfer(c: &mut Ctl, slots: &mut PolicySlots<'_>, image: &[u8]) -> Option<u32> {
    let r = feed(c, slots, &sdo_block_download(NODE, PROGRAM_DATA, 1, image));
    assert_eq!(r[0][0], 0xA4, "initiate: {:02x?}", r[0]);
    let end = r.last().unwrap();
    if let Some(code) = sdo_abort_code(end) {
        return Some(code);
    }
    for ack in &r[1..r.len() - 1] {
        assert_eq!(ack[0], 0xA2);
    }
    assert_eq!(end[0], 0xA1);
    None
}

fn started(slots: &mut PolicySlots<'_>) -> Ctl {
    let mut c = Ctl::new(ControllerConfig::default());
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame_slots(&nmt_frame(NmtCommand::Start, NODE), &clock, slots);
    c
}

/// A pre-operational controller on the active slot.
fn attached(slots: &PolicySlots<'_>) -> Ctl {
    let mut c = Ctl::new(ControllerConfig::default());
    c.poll(&MockClock::new(0));
    c.attach_slots(slots).unwrap();
    c
}

/// The actions of `n` trace observations through the controller (operational first).
fn run(c: &mut Ctl, slots: &mut PolicySlots<'_>, n: usize, t0: u64) -> Vec<[f32; ACT_DIM]> {
    let clock = MockClock::new(t0);
    // A fresh plant-side sender: one observation before the start resynchronises the
    // controller's end-to-end counters (it is not evaluated outside operational).
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    for f in encode_observation(NODE, &observation_trace(1, 9)[0], 0, &mut tx) {
        c.on_frame_slots(&f, &clock, slots);
    }
    c.on_frame_slots(&nmt_frame(NmtCommand::Start, NODE), &clock, slots);
    assert_eq!(c.state(), State::Operational);
    let out = trace_actions(c, &clock, &mut tx, n, t0, |c, f| {
        c.on_frame_slots(f, &clock, slots)
    });
    c.on_frame_slots(&nmt_frame(NmtCommand::Stop, NODE), &clock, slots);
    out
}

/// Steps an operational controller through `n` trace observations at 20 Hz from `t0`, each
/// delivered by `deliver` (with or without the slots), checks each gives one action, and returns
/// the actions.
fn trace_actions<'p>(
    c: &mut Controller<'p, 64>,
    clock: &MockClock,
    tx: &mut [E2eSender; OBS_FRAMES],
    n: usize,
    t0: u64,
    mut deliver: impl FnMut(&mut Controller<'p, 64>, &CanFrame) -> Outbox,
) -> Vec<[f32; ACT_DIM]> {
    let mut out = Vec::new();
    for (k, obs) in observation_trace(n, 5).iter().enumerate() {
        clock.set(t0 + 50_000 * (k as u64 + 1));
        c.poll(clock);
        let mut sent = 0;
        for f in encode_observation(NODE, obs, (k + 1) as u8 & 0x0F, tx) {
            sent += deliver(c, &f)
                .iter()
                .filter(|a| {
                    let id = a.standard_id().unwrap();
                    action_frame_index(NODE, id).is_some()
                })
                .count();
        }
        assert_eq!(
            sent,
            ACTION_FRAMES,
            "step {k}: one action; {:?} {:?}",
            c.state(),
            c.diagnostics()
        );
        out.push(*c.last_action());
    }
    out
}

/// The same trace through a plain controller with the file loaded directly.
fn reference(image: &[u8], n: usize) -> Vec<[f32; ACT_DIM]> {
    let file = aligned_copy(image);
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.load_policy(&view).unwrap();
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    trace_actions(&mut c, &clock, &mut tx, n, 0, |c, f| c.on_frame(f, &clock))
}

fn bits(a: &[[f32; ACT_DIM]]) -> Vec<u32> {
    a.iter().flatten().map(|x| x.to_bits()).collect()
}

/// Mounted slots with `image` transferred and activated.
fn provisioned<'r>(a: &'r mut [u8], b: &'r mut [u8], image: &[u8]) -> (PolicySlots<'r>, Ctl) {
    let mut slots = PolicySlots::mount(a, b).unwrap();
    assert_eq!(slots.active(), None, "erased storage has no active slot");
    let mut c = Ctl::new(ControllerConfig::default());
    c.poll(&MockClock::new(0));
    assert_eq!(transfer(&mut c, &mut slots, image), None);
    assert_eq!(command(&mut c, &mut slots, control::START), None);
    (slots, c)
}

#[test]
fn transfer_activate_roll_back_and_the_actions_of_each_policy() {
    let old = jaco_policy(&[16], 1).unwrap();
    let new = jaco_policy_int8(&[32, 32], 2).unwrap();
    let (mut ra, mut rb) = regions();
    let (mut slots, _) = provisioned(bytes(&mut ra), bytes(&mut rb), &old);
    let mut c = started(&mut slots);
    assert_eq!(
        c.state(),
        State::PreOperational,
        "no policy attached yet: 0xFF05"
    );
    c.attach_slots(&slots).unwrap();
    assert_eq!(
        bits(&run(&mut c, &mut slots, 6, 0)),
        bits(&reference(&old, 6))
    );

    // Operational: a download and a start are refused (0x0800_0022), the policy runs on.
    let clock = MockClock::new(1_000_000);
    c.on_frame_slots(&nmt_frame(NmtCommand::Start, NODE), &clock, &mut slots);
    assert_eq!(c.state(), State::Operational);
    let r = feed(
        &mut c,
        &mut slots,
        &sdo_block_download(NODE, PROGRAM_DATA, 1, &new)[..1],
    );
    assert_eq!(sdo_abort_code(&r[0]), Some(0x0800_0022));
    assert_eq!(
        command(&mut c, &mut slots, control::START),
        Some(0x0800_0022)
    );
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Operational as u32)
    );
    assert_eq!(c.policy_info().unwrap().format_version, 1);
    c.on_frame_slots(&nmt_frame(NmtCommand::Stop, NODE), &clock, &mut slots);
    assert_eq!(transfer(&mut c, &mut slots, &new), None);
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (true, 0),
        "verified, staged"
    );
    assert_eq!(
        read_u32(&mut c, &mut slots, PROGRAM_ID),
        CRC32.checksum(&old)
    );
    assert_eq!(command(&mut c, &mut slots, control::START), None);
    assert_eq!(c.policy_info().unwrap().format_version, 2);
    assert_eq!(flash_status(&mut c, &mut slots), (false, 0));
    assert_eq!(
        read_u32(&mut c, &mut slots, PROGRAM_ID),
        CRC32.checksum(&new)
    );
    assert!(slots.previous().is_some() && slots.on_trial());
    assert_eq!(
        bits(&run(&mut c, &mut slots, 6, 2_000_000)),
        bits(&reference(&new, 6))
    );
    assert!(!slots.on_trial(), "evaluated: no longer on trial");

    // Explicit roll-back, and back again: the slots swap, no bytes move.
    assert_eq!(command(&mut c, &mut slots, control::ROLL_BACK), None);
    assert_eq!(slots.active_crc(), CRC32.checksum(&old));
    assert_eq!(
        bits(&run(&mut c, &mut slots, 6, 3_000_000)),
        bits(&reference(&old, 6))
    );
    assert_eq!(command(&mut c, &mut slots, control::ROLL_BACK), None);
    assert_eq!(slots.active_crc(), CRC32.checksum(&new));
    // A new transfer discards the previous policy: nothing to roll back to.
    let r = feed(
        &mut c,
        &mut slots,
        &sdo_block_download(NODE, PROGRAM_DATA, 1, &old)[..3],
    );
    assert_eq!(r, vec![vec![0xA4, 0x50, 0x1F, 1, 127, 0, 0, 0]]);
    // (Inside a sub-block every frame is a segment: the client aborts the download first.)
    feed(&mut c, &mut slots, &[client_abort(PROGRAM_DATA, 1)]);
    assert_eq!(
        command(&mut c, &mut slots, control::ROLL_BACK),
        Some(0x0800_0024)
    );
    assert_eq!(slots.active_crc(), CRC32.checksum(&new));

    // What a reset finds: the newest committed activation.
    let _ = slots.into_regions(); // a reset: the RAM state is gone
    let slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    assert_eq!(slots.active_crc(), CRC32.checksum(&new));
    assert_eq!(
        slots.previous(),
        None,
        "its transfer had invalidated the other slot"
    );
}

#[test]
fn bad_transfers_and_refused_files_leave_the_active_slot() {
    let old = jaco_policy(&[16], 1).unwrap();
    let new = jaco_policy(&[8, 8], 2).unwrap();
    let (mut ra, mut rb) = regions();
    let (mut slots, mut c) = provisioned(bytes(&mut ra), bytes(&mut rb), &old);
    let old_crc = CRC32.checksum(&old);
    // A corrupt segment: the block download's CRC-16 catches it (0x0504_0004).
    let mut frames = sdo_block_download(NODE, PROGRAM_DATA, 1, &new);
    let mid = frames.len() / 2;
    let mut d = frames[mid].data().to_vec();
    d[4] ^= 0x10;
    frames[mid] = CanFrame::standard(frames[mid].standard_id().unwrap(), &d).unwrap();
    let r = feed(&mut c, &mut slots, &frames);
    assert_eq!(sdo_abort_code(r.last().unwrap()), Some(0x0504_0004));
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Aborted as u32)
    );
    // A corrupt file sent intact (the file's own CRC catches it): 0x0800_0020.
    let mut bad = new.clone();
    let k = bad.len() / 2;
    bad[k] ^= 0x40;
    assert_eq!(transfer(&mut c, &mut slots, &bad), Some(0x0800_0020));
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Format as u32)
    );
    // A valid file on another layout: refused by the controller, 0x0800_0020.
    let other = {
        let (mut body, values) = dex_policy::synth::synth_parts(&dex_policy::synth::SynthSpec {
            task: dex_policy::Task::Stack,
            observation: &[("obs", OBS_DIM as u16)],
            action: &[("j", 1.0, -1.0, 1.0); ACT_DIM],
            hidden: &[8],
            hidden_activation: dex_policy::Activation::Relu,
            output_activation: dex_policy::Activation::Tanh,
            seed: 3,
        })
        .unwrap();
        body.control_period_us = 50_000;
        dex_policy::encode_to_vec(&body, &values).unwrap()
    };
    assert_eq!(transfer(&mut c, &mut slots, &other), Some(0x0800_0020));
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Refused as u32)
    );
    // Too large: refused at the initiate (0x0607_0012).
    let r = feed(
        &mut c,
        &mut slots,
        &sdo_block_download(NODE, PROGRAM_DATA, 1, &vec![0u8; REGION])[..1],
    );
    assert_eq!(sdo_abort_code(&r[0]), Some(0x0607_0012));
    // A segment lost in a sub-block: its acknowledgement names the last segment received in
    // order, so the client repeats from there.
    let frames = sdo_block_download(NODE, PROGRAM_DATA, 1, &new);
    assert!(frames.len() > 130, "more than one sub-block");
    let mut sub = vec![frames[0], frames[1]];
    sub.extend_from_slice(&frames[3..=127]);
    let r = feed(&mut c, &mut slots, &sub);
    assert_eq!(r.len(), 2, "{r:02x?}");
    assert_eq!(r[1], [0xA2, 1, 127, 0, 0, 0, 0, 0]);
    // The client aborts (no answer); a segment with no transfer is an unknown command.
    assert!(feed(&mut c, &mut slots, &[client_abort(PROGRAM_DATA, 1)]).is_empty());
    let r = feed(&mut c, &mut slots, &[frames[2]]);
    assert_eq!(sdo_abort_code(&r[0]), Some(0x0504_0001));
    assert_eq!(
        command(&mut c, &mut slots, control::START),
        Some(0x0800_0024)
    );
    assert_eq!(slots.active_crc(), old_crc);
    assert_eq!(command(&mut c, &mut slots, 0x09), Some(0x0609_0030));
}

#[test]
fn a_silent_client_is_aborted_at_the_controllers_clock_and_the_old_policy_stays() {
    let old = jaco_policy(&[16], 1).unwrap();
    let new = jaco_policy(&[8, 8], 2).unwrap();
    let (mut ra, mut rb) = regions();
    let (mut slots, mut c) = provisioned(bytes(&mut ra), bytes(&mut rb), &old);
    let frames = sdo_block_download(NODE, PROGRAM_DATA, 1, &new);
    feed(&mut c, &mut slots, &frames[..40]);
    // The SDO server's timeout runs on the controller's clock, through poll_slots.
    let out = c.poll_slots(&MockClock::new(500_000), &mut slots);
    assert!(responses(&out).is_empty(), "not yet");
    let out = c.poll_slots(&MockClock::new(1_100_000), &mut slots);
    let r = responses(&out);
    assert_eq!(r.len(), 1);
    assert_eq!(r[0][..4], [0x80, 0x50, 0x1F, 1]);
    assert_eq!(sdo_abort_code(&r[0]), Some(0x0504_0000));
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Aborted as u32)
    );
    assert_eq!(slots.active_crc(), CRC32.checksum(&old));
    assert_eq!(
        command(&mut c, &mut slots, control::START),
        Some(0x0800_0024)
    );
    // NMT reset communication also drops a running download (no answer).
    feed(&mut c, &mut slots, &frames[..40]);
    let r = feed(
        &mut c,
        &mut slots,
        &[nmt_frame(NmtCommand::ResetCommunication, NODE)],
    );
    assert!(r.is_empty());
    assert_eq!(
        flash_status(&mut c, &mut slots),
        (false, FlashResult::Aborted as u32)
    );
    // The emergencies the controller sent are in 0x1003 (none so far), read over the same server.
    let r = feed(&mut c, &mut slots, &[sdo_read(NODE, 0x1003, 0).unwrap()]);
    assert_eq!(r[0][..5], [0x4F, 0x03, 0x10, 0, 0]);
}

#[test]
fn a_policy_whose_first_evaluation_faults_is_rolled_back_with_emcy_0xff07() {
    let old = jaco_policy(&[16], 1).unwrap();
    let faulty = jaco_policy_faulting(8, 4).unwrap();
    let (mut ra, mut rb) = regions();
    let (mut slots, mut c) = provisioned(bytes(&mut ra), bytes(&mut rb), &old);
    c.attach_slots(&slots).unwrap();
    assert_eq!(
        transfer(&mut c, &mut slots, &faulty),
        None,
        "it verifies: it loads"
    );
    assert_eq!(command(&mut c, &mut slots, control::START), None);
    assert!(slots.on_trial());
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame_slots(&nmt_frame(NmtCommand::Start, NODE), &clock, &mut slots);
    assert_eq!(c.state(), State::Operational);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let obs = observation_trace(1, 5)[0];
    let mut out = Vec::new();
    for f in encode_observation(NODE, &obs, 9, &mut tx) {
        out.extend(c.on_frame_slots(&f, &clock, &mut slots));
    }
    let emcy: Vec<&CanFrame> = out
        .iter()
        .filter(|f| f.standard_id() == Some(EMCY_BASE_ID + u16::from(NODE)))
        .collect();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data()[..5], [0x07, 0xFF, 0x81, 7, 3]);
    assert_eq!(c.state(), State::SafeStop);
    assert_eq!(c.fault(), FaultCode::PolicyRolledBack);
    assert_eq!(
        c.last_action(),
        &[0.0; ACT_DIM],
        "the safe action, not the faulty one"
    );
    assert_eq!(slots.active_crc(), CRC32.checksum(&old));
    assert!(!slots.on_trial());
    assert_eq!(slots.previous(), None, "the faulty policy is not kept");
    // The emergency is in the error history (0x1003:1: fault code 7, error code 0xFF07).
    let r = feed(&mut c, &mut slots, &[sdo_read(NODE, 0x1003, 1).unwrap()]);
    assert_eq!(r[0][4..8], 0x0007_FF07u32.to_le_bytes());
    // NMT start runs the old policy again, bit for bit.
    let got = run(&mut c, &mut slots, 4, 1_000_000);
    assert_eq!(bits(&got), bits(&reference(&old, 4)));
    // And a reset mounts the old one, never the faulty one.
    let _ = slots.into_regions(); // a reset: the RAM state is gone
    let slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    assert_eq!(slots.active_crc(), CRC32.checksum(&old));
    assert_eq!(slots.previous(), None);
}

#[test]
fn a_fault_after_the_first_evaluation_is_the_usual_fault() {
    // The faulty file attached at start-up is not on trial: no roll-back, the Fault state.
    let faulty = jaco_policy_faulting(8, 4).unwrap();
    let (mut ra, mut rb) = regions();
    let (slots, _) = provisioned(bytes(&mut ra), bytes(&mut rb), &faulty);
    let _ = slots.into_regions(); // a reset: the RAM state is gone
    let mut slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    let mut c = Ctl::new(ControllerConfig::default());
    c.attach_slots(&slots).unwrap();
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame_slots(&nmt_frame(NmtCommand::Start, NODE), &clock, &mut slots);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    for f in encode_observation(NODE, &observation_trace(1, 5)[0], 1, &mut tx) {
        c.on_frame_slots(&f, &clock, &mut slots);
    }
    assert_eq!(c.state(), State::Fault);
    assert_eq!(c.fault(), FaultCode::ActionNonFinite);
}

/// The regions with `old` active, then everything a transfer of `new` cut after `cut` bytes
/// wrote; mounted again as after a power cut.
#[test]
fn a_power_cut_at_every_byte_of_a_transfer_leaves_the_active_slot_running() {
    let old = jaco_policy(&[8], 1).unwrap();
    let new = jaco_policy(&[12], 2).unwrap();
    let (mut ra, mut rb) = regions();
    {
        let (mut slots, mut c) = provisioned(bytes(&mut ra), bytes(&mut rb), &old);
        // A previous transfer of `new` completed into the other slot and rolled back to: both
        // slots valid, so the cut transfer overwrites a slot that held a policy.
        assert_eq!(transfer(&mut c, &mut slots, &new), None);
        assert_eq!(command(&mut c, &mut slots, control::START), None);
        assert_eq!(command(&mut c, &mut slots, control::ROLL_BACK), None);
        assert_eq!(slots.active_crc(), CRC32.checksum(&old));
    }
    let active_before = (ra.clone(), rb.clone());
    let which = {
        let s = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
        s.active_index().unwrap()
    };
    let expect = bits(&reference(&old, 2));
    let frames = sdo_block_download(NODE, PROGRAM_DATA, 1, &new);
    for cut in 0..=new.len() {
        let (mut a, mut b) = active_before.clone();
        {
            let mut slots = PolicySlots::mount(bytes(&mut a), bytes(&mut b)).unwrap();
            let mut c = Ctl::new(ControllerConfig::default());
            feed(&mut c, &mut slots, &frames[..1]);
            let full = cut / 7;
            feed(&mut c, &mut slots, &frames[1..1 + full]);
            if cut % 7 != 0 {
                // The power fails inside a segment's write: only its first bytes land.
                let _ = slots.write_at(full * 7, &frames[1 + full].data()[1..1 + cut % 7]);
            }
        } // power cut: RAM state gone
        let active_region = |a: &[u64], b: &[u64]| if which == 0 { a.to_vec() } else { b.to_vec() };
        assert_eq!(
            active_region(&a, &b),
            active_region(&active_before.0, &active_before.1),
            "cut at {cut}: the active slot's bytes were written"
        );
        let mut slots = PolicySlots::mount(bytes(&mut a), bytes(&mut b)).unwrap();
        assert_eq!(slots.active_index(), Some(which), "cut at {cut}");
        assert_eq!(slots.active_crc(), CRC32.checksum(&old), "cut at {cut}");
        if cut % 97 == 0 {
            let mut c = attached(&slots);
            assert_eq!(bits(&run(&mut c, &mut slots, 2, 0)), expect, "cut at {cut}");
        }
    }
}

#[test]
fn a_power_cut_at_every_byte_of_the_commit_activates_all_or_nothing() {
    let old = jaco_policy(&[8], 1).unwrap();
    let new = jaco_policy(&[12], 2).unwrap();
    let (mut ra, mut rb) = regions();
    {
        provisioned(bytes(&mut ra), bytes(&mut rb), &old);
    }
    let inactive = 1; // erased storage: the first file went to slot 0
    let mut before = (ra.clone(), rb.clone());
    {
        let mut slots = PolicySlots::mount(bytes(&mut before.0), bytes(&mut before.1)).unwrap();
        let mut c = Ctl::new(ControllerConfig::default());
        assert_eq!(transfer(&mut c, &mut slots, &new), None);
    }
    let mut after = before.clone();
    {
        let mut slots = PolicySlots::mount(bytes(&mut after.0), bytes(&mut after.1)).unwrap();
        let mut c = Ctl::new(ControllerConfig::default());
        assert_eq!(transfer(&mut c, &mut slots, &new), None);
        assert_eq!(command(&mut c, &mut slots, control::START), None);
    }
    // The commit writes only the inactive slot's header.
    assert_eq!(before.0, after.0);
    let (b, a): (&[u8], &[u8]) = (
        bytemuck::cast_slice(&before.1),
        bytemuck::cast_slice(&after.1),
    );
    let changed: Vec<usize> = (0..b.len()).filter(|&i| a[i] != b[i]).collect();
    assert!(!changed.is_empty() && *changed.last().unwrap() < SLOT_HEADER_BYTES);
    for k in 0..=SLOT_HEADER_BYTES {
        let mut region = before.1.clone();
        bytes(&mut region)[..k].copy_from_slice(&a[..k]);
        let mut r0 = before.0.clone();
        let committed =
            bytemuck::cast_slice::<u64, u8>(&region)[..SLOT_HEADER_BYTES] == a[..SLOT_HEADER_BYTES];
        let slots = PolicySlots::mount(bytes(&mut r0), bytes(&mut region)).unwrap();
        let want = if committed { &new } else { &old };
        assert_eq!(
            slots.active_crc(),
            CRC32.checksum(want),
            "header cut at {k}"
        );
        assert_eq!(
            slots.active_index(),
            Some(usize::from(committed) * inactive)
        );
    }
    // The file bytes can be read back as they were sent.
    let mut r0 = after.0.clone();
    let mut r1 = after.1.clone();
    let slots = PolicySlots::mount(bytes(&mut r0), bytes(&mut r1)).unwrap();
    assert_eq!(slots.active_file(), &new[..]);
    let view = PolicyView::decode(slots.active_file()).unwrap();
    assert!(Mlp::<64>::new(&view).is_ok());
}

#[test]
fn regions_must_be_aligned_and_large_enough() {
    let mut a = vec![0u64; 64];
    let mut b = vec![0u64; 64];
    let ab: &mut [u8] = bytemuck::cast_slice_mut(&mut a);
    assert_eq!(
        PolicySlots::mount(&mut ab[1..257], bytes(&mut b)).unwrap_err(),
        SlotError::Misaligned
    );
    let ab: &mut [u8] = bytemuck::cast_slice_mut(&mut a);
    assert_eq!(
        PolicySlots::mount(&mut ab[..SLOT_HEADER_BYTES], bytes(&mut b)).unwrap_err(),
        SlotError::RegionTooSmall
    );
    let mut slots = PolicySlots::mount(bytes(&mut a), bytes(&mut b)).unwrap();
    assert_eq!(slots.capacity(), 512 - SLOT_HEADER_BYTES);
    let image = jaco_policy(&[8], 1).unwrap();
    assert!(image.len() > slots.capacity());
    assert_eq!(slots.begin(image.len()), Err(SlotError::TooLarge));
}
