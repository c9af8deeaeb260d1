//! The golden flash recording for the firmware check: the CAN frames of a real flash over the
//! virtual bus (hil-sim's SDO client, `dex_hil_sim::flash::flash`: a block download of the int8
//! golden policy `runtime/tests/golden/jaco_64_int8.dxpl` into 0x1F50:1, program control 0x1F51:1
//! = 1, then 0x1F56:1 read back) into a controller node running the f32 golden policy.
//! `scripts/firmware-check.sh` feeds the requests to the firmware's controller and compares its
//! responses with the recorded ones.
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
use dex_hil_sim::client::{BusClient, ClientError, Received};
use dex_hil_sim::flash::{Transfer, flash};
use dex_hil_sim::node::{NodePort, TimeMode, spawn_controller_node};
use dex_runtime::can::CanFrame;
use dex_runtime::controller::SDO_RESPONSE_BASE;
use dex_runtime::slots::CRC32;
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

/// The tool's port, recording the requests it sends and the SDO responses it receives.
struct Recording<'a> {
    inner: BusClient,
    out: &'a mut Vec<u8>,
}

impl NodePort for Recording<'_> {
    fn queue(&mut self, frame: &CanFrame) {
        record(self.out, 0, frame);
        self.inner.queue(frame);
    }

    fn flush(&mut self) -> Result<(), ClientError> {
        self.inner.flush()
    }

    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError> {
        let r = self.inner.receive_timeout(timeout)?;
        if let Some(Received::Frame(f, _)) = &r
            && f.standard_id() == Some(SDO_RESPONSE_BASE + u16::from(NODE))
        {
            record(self.out, 1, f);
        }
        Ok(r)
    }
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
    let mut out = Vec::new();
    let mut tool = Recording {
        inner: BusClient::connect(bus.addr(), "vcan0").unwrap(),
        out: &mut out,
    };
    let done = flash(
        &mut tool,
        NODE,
        &new,
        Transfer::Block,
        Duration::from_secs(10),
    )
    .unwrap();
    assert_eq!(done.crc, CRC32.checksum(&new));
    assert_eq!(done.transfer, Transfer::Block);
    drop(tool);
    stop.store(true, Ordering::SeqCst);
    node.join().unwrap().unwrap();
    bus.shutdown();
    // Requests and responses alternate as the protocol says: every response answers the
    // request before it, and no response is an abort.
    let frames: Vec<&[u8]> = out.chunks(12).collect();
    let responses: Vec<&[u8]> = frames.iter().copied().filter(|f| f[0] == 1).collect();
    assert!(
        responses.iter().all(|r| r[4] != 0x80),
        "an abort in the recording"
    );
    assert_eq!(responses[0][4], 0xA4, "block download initiated");
    let tail: Vec<u8> = responses.iter().rev().take(3).map(|r| r[4]).collect();
    assert_eq!(
        tail,
        [0x43, 0x60, 0xA1],
        "read 0x1F56, start, end of block download"
    );
    let last = responses.last().unwrap();
    assert_eq!(&last[5..8], &[0x56, 0x1F, 1]);
    assert_eq!(last[8..12], CRC32.checksum(&new).to_le_bytes());
    assert_eq!(frames.len() - responses.len(), done.requests);

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
