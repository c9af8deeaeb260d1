//! The two slot regions in RAM (`.bss`), handed out once.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, Ordering};

use dex_runtime::slots::SLOT_HEADER_BYTES;

/// Largest policy file a slot takes: 32 KiB (the 44-64-64-9 f32 golden, the int8 Reach policy).
pub const SLOT_FILE_BYTES: usize = 32 * 1024;
/// One region: header and file.
pub const REGION: usize = SLOT_FILE_BYTES + SLOT_HEADER_BYTES;

/// One region, 8-byte aligned.
#[repr(C, align(8))]
struct Region(UnsafeCell<[u8; REGION]>);

/// Both regions.
struct Regions([Region; 2]);

// SAFETY: the regions are only reached through `take`, which hands them out once.
unsafe impl Sync for Regions {}

static REGIONS: Regions = Regions([
    Region(UnsafeCell::new([0; REGION])),
    Region(UnsafeCell::new([0; REGION])),
]);
static TAKEN: AtomicBool = AtomicBool::new(false);

/// Both regions, once per boot.
pub fn take() -> Option<(&'static mut [u8], &'static mut [u8])> {
    if TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    let [a, b] = &REGIONS.0;
    // SAFETY: `TAKEN` lets this run once, so these are the only references to the regions.
    Some(unsafe { (&mut *a.0.get(), &mut *b.0.get()) })
}
