//! CAN FD on the bus (`hil-sim bus --fd --data-bitrate D`): an FD frame takes its bits over the
//! two bit rates, frames written together go lowest identifier first (FD and classic alike),
//! timestamps are at least a frame apart; a classic bus refuses FD frames; the FD closed loop in
//! lockstep gives the classic loop's actions bit for bit and the same log twice; malformed FD
//! frames are refused and counted by the controller node; `--data-bitrate` without `--fd` and a
//! data rate below the nominal one are refused.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::client::{BusClient, Received};
use dex_hil_sim::latency::{analyse_any, parse_trace_any};
use dex_hil_sim::node::{NodeConfig, NodeTiming, TimeMode, spawn_controller_node};
use dex_hil_sim::plant::SyntheticPlant;
use dex_hil_sim::wire::{Stuffing, WireConfig};
use dex_hil_sim::wire_fd::BusWire;
use dex_runtime::can::fd_messages::{FD_OBS_LEN, fd_observation_frame_index};
use dex_runtime::can::messages::{NmtCommand, nmt_frame, rpdo_cob_id};
use dex_runtime::can::{AnyFrame, CanFrame, FdFrame, FrameLayout};
use dex_runtime::testkit::jaco_policy;

const NOMINAL: WireConfig = WireConfig {
    bitrate: 500_000,
    stuffing: Stuffing::Exact,
};
const DATA_BITRATE: u32 = 2_000_000;
const WIRE: BusWire = BusWire {
    nominal: NOMINAL,
    data_bitrate: Some(DATA_BITRATE),
};
/// One nominal bit at 500 kbit/s, in microseconds.
const BIT_US: u64 = 2;

fn fd_bus(fd_data_bitrate: Option<u32>) -> (Bus, BusClient, BusClient) {
    let bus = Bus::start(BusConfig {
        clock: BusClock::Virtual,
        wire: Some(NOMINAL),
        fd_data_bitrate,
        ..BusConfig::default()
    })
    .unwrap();
    let tx = BusClient::connect(bus.addr(), "vcan0").unwrap();
    let mut rx = BusClient::connect(bus.addr(), "vcan0").unwrap();
    let mut probe = BusClient::connect(bus.addr(), "vcan0").unwrap();
    loop {
        probe.queue(&CanFrame::standard(0x7E5, &[0; 8]).unwrap());
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

fn receive(rx: &mut BusClient, n: usize) -> Vec<(AnyFrame, u64)> {
    let mut got = Vec::new();
    while got.len() < n {
        match rx.receive_timeout(Duration::from_secs(5)).unwrap() {
            Some(Received::Frame(f, ts)) if f.standard_id() != Some(0x7E5) => {
                got.push((AnyFrame::Classic(f), ts))
            }
            Some(Received::Fd(f, ts)) => got.push((AnyFrame::Fd(f), ts)),
            Some(_) => {}
            None => panic!("only {} of {n} frames arrived", got.len()),
        }
    }
    got
}

#[test]
fn fd_frames_take_their_bits_over_both_rates_lowest_identifier_first() {
    let (bus, mut tx, mut rx) = fd_bus(Some(DATA_BITRATE));
    bus.set_time(10_000);
    let obs1 = FdFrame::standard(0x310, &[0x00; 48]).unwrap();
    let obs0 = FdFrame::standard(0x210, &[0x5A; 48]).unwrap();
    let action = FdFrame::standard(0x190, &[0x33; 20]).unwrap();
    tx.queue_fd(&obs1);
    tx.queue(&CanFrame::standard(0x700, &[0x7F]).unwrap());
    tx.queue_fd(&obs0);
    tx.queue_fd(&action);
    tx.flush().unwrap();
    let got = receive(&mut rx, 4);
    let ids: Vec<_> = got.iter().map(|(f, _)| f.standard_id().unwrap()).collect();
    assert_eq!(ids, [0x190, 0x210, 0x310, 0x700]);
    assert!(got[..3].iter().all(|(f, _)| f.is_fd()) && !got[3].0.is_fd());
    let mut start = 10_000;
    for (f, ts) in &got {
        // Its nominal bits at 500 kbit/s and its data-phase bits at 2 Mbit/s, within one bit.
        let want_us = WIRE.frame_ns(f) as f64 / 1e3;
        assert!(
            ((ts - start) as f64 - want_us).abs() < BIT_US as f64,
            "{f:?}: {ts} - {start}, want {want_us} us"
        );
        // At least one frame apart: the next starts when this one ends.
        start = *ts;
    }
    // The data phase at 2 Mbit/s: a 48-byte FD frame is far shorter than at one rate.
    let (obs_us, slow_us) = (
        WIRE.frame_ns(&got[1].0),
        BusWire::from(NOMINAL).frame_ns(&got[1].0),
    );
    assert!(obs_us * 2 < slow_us, "{obs_us} vs {slow_us}");
    bus.shutdown();
}

#[test]
fn a_classic_bus_refuses_fd_frames() {
    let (bus, mut tx, mut rx) = fd_bus(None);
    bus.set_time(1_000);
    tx.queue_fd(&FdFrame::standard(0x210, &[0; 48]).unwrap());
    tx.queue(&CanFrame::standard(0x211, &[1]).unwrap());
    tx.flush().unwrap();
    let got = receive(&mut rx, 1);
    assert_eq!(got[0].0.standard_id(), Some(0x211));
    assert!(
        rx.receive_timeout(Duration::from_millis(200))
            .unwrap()
            .is_none()
    );
    assert_eq!(bus.stats().unknown_messages, 1);
    bus.shutdown();
}

#[test]
fn the_fd_closed_loop_gives_the_classic_actions_bit_for_bit_and_the_same_log_twice() {
    let policy = jaco_policy(&[64, 64], 5).unwrap();
    let episodes = [(21, 30), (22, 30)];
    let dir = std::env::temp_dir().join(format!("hil-sim-fd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let compute_us = 885;
    let run = |log: &str| {
        common::lockstep_over_an_fd_wire(
            &policy,
            &mut SyntheticPlant::new(30),
            &episodes,
            Some(NOMINAL),
            Some(DATA_BITRATE),
            compute_us,
            Some(dir.join(log)),
        )
    };
    let (fd, reports) = run("a.log");
    for r in &reports {
        assert_eq!((r.steps, r.steps_without_action), (30, 0));
    }
    let (classic, classic_reports) = common::lockstep_over_a_wire(
        &policy,
        &mut SyntheticPlant::new(30),
        &episodes,
        Some(NOMINAL),
        compute_us,
        None,
    );
    assert_eq!(fd.len(), 60);
    assert_eq!(
        fd.iter().map(|a| a.map(f32::to_bits)).collect::<Vec<_>>(),
        classic
            .iter()
            .map(|a| a.map(f32::to_bits))
            .collect::<Vec<_>>(),
        "the same quantised inputs, the same actions"
    );
    assert_eq!(reports, classic_reports);
    let (again, _) = run("b.log");
    assert_eq!(again, fd);
    let log = std::fs::read_to_string(dir.join("a.log")).unwrap();
    assert_eq!(
        log,
        std::fs::read_to_string(dir.join("b.log")).unwrap(),
        "deterministic"
    );
    let trace = parse_trace_any(&log).unwrap();
    for w in trace.windows(2) {
        assert!(
            w[1].0 - w[0].0 + 1 >= WIRE.frame_ns(&w[1].1) / 1000,
            "{w:?}"
        );
    }
    // Two observation frames per cycle, FD, in identifier order.
    let obs: Vec<usize> = trace
        .iter()
        .filter(|(_, f)| f.is_fd())
        .filter_map(|(_, f)| fd_observation_frame_index(0x10, f.standard_id()?))
        .collect();
    assert_eq!(obs.len(), 120);
    assert!(obs.chunks(2).all(|c| c == [0, 1]));
    let r = analyse_any(&trace, 0x10, FrameLayout::Fd, WIRE, compute_us * 1000).unwrap();
    assert_eq!((r.cycles.len(), r.unanswered), (60, 0));
    // Queuing: the SYNC ahead of the observation, and on some cycles an emergency (the
    // envelope's warning, 0x090) that wins arbitration over the action.
    for c in &r.cycles {
        assert!(c.queuing_ns < 600_000, "{c:?}");
        assert!(c.total_ns < 2_000_000, "{c:?}");
    }
    assert!(r.cycles.iter().any(|c| c.queuing_ns < 150_000));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn malformed_fd_frames_are_refused_and_counted_by_the_node() {
    let bus = Bus::start(BusConfig {
        clock: BusClock::Virtual,
        wire: Some(NOMINAL),
        fd_data_bitrate: Some(DATA_BITRATE),
        ..BusConfig::default()
    })
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let status = bus.status_slot();
    let node = spawn_controller_node(
        bus.addr(),
        Some(jaco_policy(&[64, 64], 5).unwrap()),
        NodeConfig {
            controller: dex_runtime::ControllerConfig::default(),
            layout: FrameLayout::Fd,
        },
        NodeTiming::from(TimeMode::Lockstep),
        Arc::clone(&stop),
        Some(Arc::clone(&status)),
    )
    .unwrap();
    let mut tx = BusClient::connect(bus.addr(), "vcan0").unwrap();
    std::thread::sleep(Duration::from_millis(100));
    tx.queue(&nmt_frame(NmtCommand::Start, 0x10));
    // Wrong length (64 bytes), then a bad E2E CRC on a 48-byte frame, then a classic frame on
    // the FD observation identifier.
    tx.queue_fd(&FdFrame::standard(rpdo_cob_id(0x10, 0), &[0; 64]).unwrap());
    tx.queue_fd(&FdFrame::standard(rpdo_cob_id(0x10, 1), &[0x11; FD_OBS_LEN]).unwrap());
    tx.queue(&CanFrame::standard(rpdo_cob_id(0x10, 0), &[0; 8]).unwrap());
    tx.flush().unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    loop {
        let line = status.lock().unwrap().clone();
        if line.contains("e2e_errors=3") {
            assert!(line.contains("evaluations=0"), "{line}");
            break;
        }
        assert!(std::time::Instant::now() < deadline, "{line}");
        std::thread::sleep(Duration::from_millis(20));
    }
    stop.store(true, Ordering::SeqCst);
    node.join().unwrap().unwrap();
    bus.shutdown();
}

#[test]
fn data_bitrate_without_fd_and_below_the_nominal_rate_is_refused() {
    let exe = env!("CARGO_BIN_EXE_hil-sim");
    for (args, says) in [
        (
            &["bus", "--data-bitrate", "2000000", "--seconds", "0.1"][..],
            "needs --fd",
        ),
        (
            &[
                "bus",
                "--fd",
                "--bitrate",
                "1000000",
                "--data-bitrate",
                "500000",
                "--seconds",
                "0.1",
            ][..],
            "below the nominal",
        ),
    ] {
        let out = std::process::Command::new(exe).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
}
