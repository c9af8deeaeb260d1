//! The golden flash recording for the firmware check: the CAN frames of a real flash over the
//! virtual bus (python-can's protocol, `tests/test_sil_flash.py`) of the int8 golden policy
//! (`runtime/tests/golden/jaco_64_int8.dxpl`) into a controller node running the f32 golden
//! policy, then its activation. `scripts/firmware-check.sh` feeds the requests to the firmware's
//! controller and compares its responses with the recorded ones.
//!
//! Re-make it: `DEX_BLESS=1 cargo test -p dex-hil-sim --test flash_golden`; without `DEX_BLESS`
//! the test fails when the recording would differ from the committed file.
//!
//! Format (`runtime/tests/golden/flash_int8.frames`): 12 bytes per frame in bus order: direction
//! (0 request to the controller, 1 response), data length, CAN id u16 LE, 8 data bytes (zero
//! padded).
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::client::{BusClient, Received};
use dex_hil_sim::node::{TimeMode, spawn_controller_node};
use dex_runtime::can::CanFrame;
use dex_runtime::slots::{BLOCK_SEGMENTS, FLASH_RESPONSE_BASE};
use dex_runtime::testkit::{flash_command, flash_frames};
use embedded_can::Frame;

const NODE: u8 = 0x10;

fn record(out: &mut Vec<u8>, direction: u8, f: &CanFrame) {
    out.push(direction);
    out.push(f.data().len() as u8);
    out.extend_from_slice(&f.standard_id().unwrap().to_le_bytes());
    let mut d = [0u8; 8];
    d[..f.data().len()].copy_from_slice(f.data());
    out.extend_from_slice(&d);
}

#[test]
fn the_golden_flash_recording_is_what_a_flash_over_the_bus_sends_and_receives() {
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime/tests/golden");
    let old = std::fs::read(golden.join("jaco_64.dxpl")).unwrap();
    let new = std::fs::read(golden.join("jaco_64_int8.dxpl")).unwrap();
    let bus = Bus::start(BusConfig {
        clock: BusClock::Virtual,
        ..BusConfig::default()
    })
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let node = spawn_controller_node(
        bus.addr(),
        Some(old),
        dex_runtime::ControllerConfig::default(),
        TimeMode::Lockstep,
        stop.clone(),
        None,
    )
    .unwrap();
    let mut tool = BusClient::connect(bus.addr(), "vcan0").unwrap();
    let mut requests = flash_frames(NODE, &new, None);
    requests.push(flash_command(NODE, 0x04).unwrap());
    let segments = requests.len() - 3;
    let mut out = Vec::new();
    for (n, f) in requests.iter().enumerate() {
        tool.queue(f);
        tool.flush().unwrap();
        record(&mut out, 0, f);
        // Answered: init, every block's last segment and the file's last, end, activate.
        let answered = n == 0 || n > segments || n % BLOCK_SEGMENTS as usize == 0 || n == segments;
        if !answered {
            continue;
        }
        loop {
            match tool.receive_timeout(Duration::from_secs(10)).unwrap() {
                Some(Received::Frame(r, _))
                    if r.standard_id() == Some(FLASH_RESPONSE_BASE + u16::from(NODE)) =>
                {
                    assert_eq!(r.data()[1], 0, "request {n}: status {}", r.data()[1]);
                    record(&mut out, 1, &r);
                    break;
                }
                Some(_) => {}
                None => panic!("request {n}: no response"),
            }
        }
    }
    assert_eq!(&out[out.len() - 12..out.len() - 8], &[1, 2, 0x90, 0x05]);
    assert_eq!(&out[out.len() - 8..out.len() - 6], &[0x84, 0]);
    stop.store(true, Ordering::SeqCst);
    node.join().unwrap().unwrap();
    bus.shutdown();

    let path = golden.join("flash_int8.frames");
    if std::env::var_os("DEX_BLESS").is_some() {
        std::fs::write(&path, &out).unwrap();
        println!("wrote {} ({} frames)", path.display(), out.len() / 12);
    } else {
        let committed = std::fs::read(&path).expect("no flash_int8.frames: run with DEX_BLESS=1");
        assert!(
            committed == out,
            "{} is stale ({} vs {} bytes): DEX_BLESS=1 cargo test -p dex-hil-sim --test flash_golden",
            path.display(),
            committed.len(),
            out.len()
        );
    }
}
