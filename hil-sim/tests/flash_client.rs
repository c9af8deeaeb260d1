//! hil-sim's SDO flash client against the controller node over the virtual bus: block and
//! segmented downloads into 0x1F50, the start on 0x1F51 and the 0x1F56 check; the node's refusals
//! come back as typed errors naming the CiA 301 abort code and its meaning, and leave the running
//! policy.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dex_hil_sim::bus::{Bus, BusConfig};
use dex_hil_sim::client::BusClient;
use dex_hil_sim::flash::{FlashError, SdoClient, SdoError, Transfer, flash};
use dex_hil_sim::node::{TimeMode, spawn_controller_node};
use dex_runtime::can::messages::{NmtCommand, nmt_frame};
use dex_runtime::canopen::program::{FLASH_STATUS, PROGRAM_ID};
use dex_runtime::slots::CRC32;
use dex_runtime::testkit::jaco_policy;

const NODE: u8 = 0x10;
const WAIT: Duration = Duration::from_secs(5);

/// Runs `f` against a real-time controller node started with `policy`, on its own bus.
fn with_node(policy: &[u8], f: impl FnOnce(&mut BusClient)) {
    let bus = Bus::start(BusConfig::default()).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let node = spawn_controller_node(
        bus.addr(),
        Some(policy.to_vec()),
        // No plant: a long watchdog keeps an NMT-started node operational.
        dex_runtime::ControllerConfig {
            watchdog_cycles: 1000,
            ..dex_runtime::ControllerConfig::default()
        },
        TimeMode::RealTime,
        stop.clone(),
        None,
    )
    .unwrap();
    let mut tool = BusClient::connect(bus.addr(), "vcan0").unwrap();
    std::thread::sleep(Duration::from_millis(150)); // boot-up: pre-operational
    f(&mut tool);
    stop.store(true, Ordering::SeqCst);
    node.join().unwrap().unwrap();
    bus.shutdown();
}

fn active(tool: &mut BusClient) -> u32 {
    let mut sdo = SdoClient::new(tool, NODE);
    sdo.timeout = WAIT;
    sdo.read_u32(PROGRAM_ID, 1).unwrap()
}

#[test]
fn block_and_segmented_flashes_start_the_file_and_report_its_crc() {
    let old = jaco_policy(&[16], 1).unwrap();
    let a = jaco_policy(&[24, 24], 2).unwrap();
    let b = jaco_policy(&[12], 3).unwrap();
    with_node(&old, |tool| {
        assert_eq!(active(tool), CRC32.checksum(&old));
        let done = flash(tool, NODE, &a, Transfer::Block, WAIT).unwrap();
        assert_eq!(done.transfer, Transfer::Block);
        assert_eq!(done.crc, CRC32.checksum(&a));
        assert_eq!(active(tool), CRC32.checksum(&a));
        let done = flash(tool, NODE, &b, Transfer::Segmented, WAIT).unwrap();
        assert_eq!(done.transfer, Transfer::Segmented);
        assert!(done.requests > b.len() / 7, "one request per segment");
        assert_eq!(active(tool), CRC32.checksum(&b));
    });
}

#[test]
fn refusals_are_typed_errors_with_the_abort_code_and_the_old_policy_runs_on() {
    let old = jaco_policy(&[16], 1).unwrap();
    let new = jaco_policy(&[8], 4).unwrap();
    with_node(&old, |tool| {
        // A corrupt file: the node verifies it at the end of the download and refuses it.
        let mut bad = new.clone();
        let k = bad.len() / 2;
        bad[k] ^= 0x01;
        let e = flash(tool, NODE, &bad, Transfer::Block, WAIT).unwrap_err();
        let FlashError::Download(ref sdo) = e else {
            panic!("{e}")
        };
        assert_eq!(sdo.abort_code(), Some(0x0800_0020), "{e}");
        let text = e.to_string();
        assert!(
            text.contains("0x08000020") && text.contains("cannot be transferred or stored"),
            "{text}"
        );
        assert_eq!(active(tool), CRC32.checksum(&old));
        // 0x1F57: the last result is "format" (2), nothing staged.
        let mut sdo = SdoClient::new(tool, NODE);
        sdo.timeout = WAIT;
        assert_eq!(sdo.read_u32(FLASH_STATUS, 1).unwrap(), 2 << 1);

        // Operational: the download is refused at its initiate with 0x0800_0022.
        tool.queue(&nmt_frame(NmtCommand::Start, NODE));
        tool.flush().unwrap();
        std::thread::sleep(Duration::from_millis(100));
        let e = flash(tool, NODE, &new, Transfer::Block, WAIT).unwrap_err();
        assert!(
            matches!(
                e,
                FlashError::Download(SdoError::Aborted {
                    index: 0x1F50,
                    sub: 1,
                    code: 0x0800_0022,
                    ..
                })
            ),
            "{e}"
        );
        assert!(e.to_string().contains("present device state"), "{e}");
        assert_eq!(active(tool), CRC32.checksum(&old));
    });
}
