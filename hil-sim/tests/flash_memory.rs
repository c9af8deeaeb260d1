//! The controller node flashed 1,000 times: its memory stays where it was after the first few
//! flashes (a counting global allocator measures the live heap bytes), every flash is verified
//! and activated, and the node's slot storage is two fixed regions. A leak of one file per
//! activation (the node before the runtime's slots) grows the heap by 1,000 files and fails here.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicIsize, Ordering};
use std::time::Duration;

use dex_hil_sim::client::{ClientError, Received};
use dex_hil_sim::flash::SlotStorage;
use dex_hil_sim::node::{NodePort, TimeMode, run_controller_node};
use dex_runtime::ControllerConfig;
use dex_runtime::can::CanFrame;
use dex_runtime::canopen::program::{PROGRAM_CONTROL, PROGRAM_DATA, PROGRAM_ID, control};
use dex_runtime::controller::SDO_RESPONSE_BASE;
use dex_runtime::slots::CRC32;
use dex_runtime::testkit::{jaco_policy, sdo_block_download, sdo_read, sdo_write};
use embedded_can::Frame;

/// Live heap bytes (allocated less freed).
static LIVE: AtomicIsize = AtomicIsize::new(0);

struct Counting;

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LIVE.fetch_add(layout.size() as isize, Ordering::Relaxed);
        // SAFETY: the caller's contract, passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LIVE.fetch_add(layout.size() as isize, Ordering::Relaxed);
        // SAFETY: the caller's contract, passed on.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size() as isize, Ordering::Relaxed);
        // SAFETY: the caller's contract, passed on.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LIVE.fetch_add(
            new_size as isize - layout.size() as isize,
            Ordering::Relaxed,
        );
        // SAFETY: the caller's contract, passed on.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

const FLASHES: usize = 1_000;
const NODE: u8 = 0x10;

/// Feeds `FLASHES` flashes (two files in turn, each an SDO block download into 0x1F50 then a
/// start on 0x1F51, a read of 0x1F56 after each) to the node and checks the answers, without
/// allocating.
struct Script {
    files: [Vec<CanFrame>; 2],
    crcs: [u32; 2],
    activate: CanFrame,
    status: CanFrame,
    flash: usize,
    pos: usize,
    t: u64,
    live_at: [isize; 2],
    activated: usize,
    bad_responses: usize,
    stop: &'static AtomicBool,
}

impl NodePort for Script {
    fn queue(&mut self, frame: &CanFrame) {
        if frame.standard_id() != Some(SDO_RESPONSE_BASE + u16::from(NODE)) {
            return;
        }
        let d = frame.data();
        let ok = match d[0] {
            0xA4 | 0xA2 | 0xA1 => true,
            0x60 => {
                self.activated += 1;
                true
            }
            0x43 => d[4..8] == self.crcs[(self.flash - 1) % 2].to_le_bytes(),
            _ => false,
        };
        self.bad_responses += usize::from(!ok);
    }

    fn flush(&mut self) -> Result<(), ClientError> {
        Ok(())
    }

    fn receive_timeout(&mut self, _: Duration) -> Result<Option<Received>, ClientError> {
        if self.flash == FLASHES {
            self.stop.store(true, Ordering::Relaxed);
            return Ok(None);
        }
        let frames = &self.files[self.flash % 2];
        let frame = match self.pos {
            p if p < frames.len() => frames[p],
            p if p == frames.len() => self.activate,
            _ => self.status,
        };
        self.pos += 1;
        if self.pos > frames.len() + 1 {
            self.pos = 0;
            self.flash += 1;
            if self.flash == 10 {
                self.live_at[0] = LIVE.load(Ordering::Relaxed);
            }
            if self.flash == FLASHES - 1 {
                self.live_at[1] = LIVE.load(Ordering::Relaxed);
            }
        }
        self.t += 100;
        Ok(Some(Received::Frame(frame, self.t)))
    }
}

#[test]
fn a_thousand_flashes_keep_the_node_memory_bounded() {
    let files = [jaco_policy(&[4], 1).unwrap(), jaco_policy(&[6], 2).unwrap()];
    let stop: &'static AtomicBool = Box::leak(Box::new(AtomicBool::new(false)));
    let mut script = Script {
        files: [
            sdo_block_download(NODE, PROGRAM_DATA, 1, &files[0]),
            sdo_block_download(NODE, PROGRAM_DATA, 1, &files[1]),
        ],
        crcs: [CRC32.checksum(&files[0]), CRC32.checksum(&files[1])],
        activate: sdo_write(NODE, PROGRAM_CONTROL, 1, &[control::START]).unwrap(),
        status: sdo_read(NODE, PROGRAM_ID, 1).unwrap(),
        flash: 0,
        pos: 0,
        t: 0,
        live_at: [0; 2],
        activated: 0,
        bad_responses: 0,
        stop,
    };
    let report = run_controller_node(
        &mut script,
        Some(&files[1]),
        ControllerConfig::default(),
        TimeMode::Lockstep,
        stop,
        None,
    )
    .unwrap();
    assert_eq!(report.load_error, None);
    assert_eq!(script.activated, FLASHES);
    assert_eq!(script.bad_responses, 0);
    let grown = script.live_at[1] - script.live_at[0];
    let file = files[0].len().min(files[1].len()) as isize;
    println!(
        "live heap after 10 flashes {} B, after {} flashes {} B (files {} / {} B)",
        script.live_at[0],
        FLASHES - 1,
        script.live_at[1],
        files[0].len(),
        files[1].len()
    );
    // Not one file's worth in 989 flashes (a leak per activation would be ~989 files).
    assert!(
        grown < file,
        "the node's heap grew by {grown} B over the flashes"
    );
    // The storage is two fixed regions: header + 512 KiB each.
    assert_eq!(SlotStorage::new().bytes(), 2 * (32 + 512 * 1024));
}
