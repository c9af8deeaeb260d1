//! The bus applies the wire model (`hil-sim bus --bitrate`): frames take their bits over the bit
//! rate, the lowest identifier goes first among frames waiting together, a frame offered while the
//! wire is busy waits for the next idle, timestamps are end of frame and at least a frame apart,
//! and a timed lockstep closed loop stays deterministic with the same actions as an untimed one.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use std::time::Duration;

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::client::{BusClient, Received};
use dex_hil_sim::latency::{analyse, parse_trace};
use dex_hil_sim::plant::SyntheticPlant;
use dex_hil_sim::wire::{Stuffing, WireConfig, bits_ns, frame_bits};
use dex_runtime::can::CanFrame;
use dex_runtime::can::messages::{OBS_FRAMES, observation_frame_index};
use dex_runtime::testkit::jaco_policy;

const WIRE: WireConfig = WireConfig {
    bitrate: 500_000,
    stuffing: Stuffing::Exact,
};
/// One bit at 500 kbit/s, in microseconds.
const BIT_US: u64 = 2;

fn frame(id: u16, fill: u8) -> CanFrame {
    CanFrame::standard(id, &[fill; 8]).unwrap()
}

fn frame_us(f: &CanFrame) -> u64 {
    bits_ns(frame_bits(f, WIRE.stuffing), WIRE.bitrate) / 1000
}

/// A bus with the wire, a sender and a subscribed receiver.
fn timed_bus(clock: BusClock) -> (Bus, BusClient, BusClient) {
    let bus = Bus::start(BusConfig {
        clock,
        wire: Some(WIRE),
        ..BusConfig::default()
    })
    .unwrap();
    let tx = BusClient::connect(bus.addr(), "vcan0").unwrap();
    let mut rx = BusClient::connect(bus.addr(), "vcan0").unwrap();
    // The receiver is subscribed once a probe reaches it.
    let mut probe = BusClient::connect(bus.addr(), "vcan0").unwrap();
    loop {
        probe.queue(&frame(0x7E5, 0));
        probe.flush().unwrap();
        if let Some(Received::Frame(f, _)) = rx.receive_timeout(Duration::from_millis(100)).unwrap()
            && f.standard_id() == Some(0x7E5)
        {
            break;
        }
    }
    while rx
        .receive_timeout(Duration::from_millis(50))
        .unwrap()
        .is_some()
    {}
    (bus, tx, rx)
}

fn receive(rx: &mut BusClient, n: usize) -> Vec<(CanFrame, u64)> {
    let mut got = Vec::new();
    while got.len() < n {
        match rx.receive_timeout(Duration::from_secs(5)).unwrap() {
            Some(Received::Frame(f, ts)) if f.standard_id() != Some(0x7E5) => got.push((f, ts)),
            Some(_) => {}
            None => panic!("only {} of {n} frames arrived", got.len()),
        }
    }
    got
}

#[test]
fn frames_written_together_go_lowest_identifier_first_each_its_bits_long() {
    let (bus, mut tx, mut rx) = timed_bus(BusClock::Virtual);
    bus.set_time(10_000);
    let sent = [frame(0x300, 0x00), frame(0x100, 0x55), frame(0x200, 0x5A)];
    for f in &sent {
        tx.queue(f);
    }
    tx.flush().unwrap();
    let got = receive(&mut rx, 3);
    let ids: Vec<_> = got.iter().map(|(f, _)| f.standard_id().unwrap()).collect();
    assert_eq!(ids, [0x100, 0x200, 0x300]);
    // The first starts when offered; each ends its bits over the bit rate later (within a bit).
    let mut start = 10_000;
    for (f, ts) in &got {
        let bits = frame_bits(f, Stuffing::Exact);
        assert!(
            (ts - start).abs_diff(u64::from(bits) * BIT_US) < BIT_US,
            "{f:?}: {ts} - {start} for {bits} bits"
        );
        start = *ts;
    }
    // All-zero data stuffs more than alternating bits: the exact lengths differ.
    assert_ne!(frame_us(&got[0].0), frame_us(&got[2].0));
    bus.shutdown();
}

#[test]
fn lockstep_frames_offered_while_the_wire_is_busy_wait_for_it() {
    let (bus, mut tx, mut rx) = timed_bus(BusClock::Virtual);
    bus.set_time(1_000);
    for _ in 0..3 {
        tx.queue(&frame(0x400, 0x11));
    }
    tx.flush().unwrap();
    let first = receive(&mut rx, 3);
    // Offered at 1.1 ms (its sender's `< txtime >`) while the wire is busy until after 2.6 ms.
    tx.queue_line("< txtime 1100 >");
    tx.queue(&frame(0x080, 0x22));
    tx.flush().unwrap();
    let late = receive(&mut rx, 1);
    let busy_until = first.last().unwrap().1;
    assert!(busy_until > 1_100);
    assert_eq!(
        late[0].1,
        busy_until + frame_us(&late[0].0),
        "starts at the idle"
    );
    // Offered after the idle: starts when offered.
    tx.queue_line("< txtime 9000 >");
    tx.queue(&frame(0x080, 0x22));
    tx.flush().unwrap();
    let idle = receive(&mut rx, 1);
    assert_eq!(idle[0].1, 9_000 + frame_us(&idle[0].0));
    bus.shutdown();
}

#[test]
fn real_time_a_lower_identifier_offered_meanwhile_wins_the_next_idle() {
    let (bus, mut tx, mut rx) = timed_bus(BusClock::Wall);
    let mut other = BusClient::connect(bus.addr(), "vcan0").unwrap();
    // 100 frames: about 25 ms on the wire.
    for _ in 0..100 {
        tx.queue(&frame(0x700, 0x33));
    }
    tx.flush().unwrap();
    std::thread::sleep(Duration::from_millis(3));
    other.queue(&frame(0x100, 0x44));
    other.flush().unwrap();
    let got = receive(&mut rx, 101);
    let at = got
        .iter()
        .position(|(f, _)| f.standard_id() == Some(0x100))
        .unwrap();
    assert!(at > 0 && at < 90, "0x100 went at place {at} of 101");
    // It waited for the frame on the wire to end, then went at once (no pre-emption, no gap).
    assert_eq!(got[at].1 - got[at - 1].1, frame_us(&got[at].0));
    // Back to back: every timestamp at least one frame after the one before.
    for w in got.windows(2) {
        assert!(w[1].1 - w[0].1 + 1 >= frame_us(&w[1].0), "{w:?}");
    }
    bus.shutdown();
}

#[test]
fn timed_lockstep_keeps_the_actions_and_stamps_a_frame_apart() {
    let policy = jaco_policy(&[64, 64], 5).unwrap();
    let episodes = [(21, 30), (22, 30)];
    let dir = std::env::temp_dir().join(format!("hil-sim-wire-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let compute_us = 3_625;
    let run = |log: &str| {
        common::lockstep_over_a_wire(
            &policy,
            &mut SyntheticPlant::new(30),
            &episodes,
            Some(WIRE),
            compute_us,
            Some(dir.join(log)),
        )
    };
    let (timed, reports) = run("a.log");
    for r in &reports {
        assert_eq!((r.steps, r.steps_without_action), (30, 0));
    }
    let (untimed, _) =
        common::lockstep_over_the_bus(&policy, &mut SyntheticPlant::new(30), &episodes);
    assert_eq!(timed, untimed, "the wire changes time, not actions");
    let (again, _) = run("b.log");
    assert_eq!(again, timed);
    let log = std::fs::read_to_string(dir.join("a.log")).unwrap();
    assert_eq!(
        log,
        std::fs::read_to_string(dir.join("b.log")).unwrap(),
        "deterministic"
    );
    let trace = parse_trace(&log).unwrap();
    for w in trace.windows(2) {
        assert!(w[1].0 - w[0].0 + 1 >= frame_us(&w[1].1), "{w:?}");
    }
    // The observation's frames reach the wire in arbitration order.
    let obs: Vec<usize> = trace
        .iter()
        .filter_map(|(_, f)| observation_frame_index(0x10, f.standard_id()?))
        .collect();
    for cycle in obs.chunks(OBS_FRAMES) {
        let ids: Vec<u16> = cycle
            .iter()
            .map(|&k| dex_runtime::can::messages::rpdo_cob_id(0x10, k))
            .collect();
        assert!(ids.is_sorted(), "{ids:03X?}");
    }
    // Every answered observation: its wire time, the compute, a little queuing (the SYNC).
    let r = analyse(&trace, 0x10, WIRE, compute_us * 1000).unwrap();
    assert_eq!(r.cycles.len(), 60);
    assert_eq!(r.unanswered, 0);
    for c in &r.cycles {
        assert!(
            c.observation_wire_ns >= 15 * 111 * 2_000 && c.observation_wire_ns <= 15 * 135 * 2_000
        );
        assert!(c.queuing_ns < 1_000_000, "{c:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn real_time_frames_written_together_go_lowest_identifier_first() {
    let (bus, mut tx, mut rx) = timed_bus(BusClock::Wall);
    for id in [0x300, 0x100, 0x200] {
        tx.queue(&frame(id, 0x5A));
    }
    tx.flush().unwrap();
    let got = receive(&mut rx, 3);
    let ids: Vec<_> = got.iter().map(|(f, _)| f.standard_id().unwrap()).collect();
    assert_eq!(ids, [0x100, 0x200, 0x300], "one write: one offer time");
    for w in got.windows(2) {
        assert_eq!(w[1].1 - w[0].1, frame_us(&w[1].0), "back to back");
    }
    bus.shutdown();
}
