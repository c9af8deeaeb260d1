//! The two slot regions in RAM (`.bss`), handed out once ([`dex_slot_mirror::SlotRegions`]).

use dex_runtime::slots::SLOT_HEADER_BYTES;
use dex_slot_mirror::SlotRegions;

/// Largest policy file a slot takes: 32 KiB (the 44-64-64-9 f32 golden, the int8 Reach policy).
pub const SLOT_FILE_BYTES: usize = 32 * 1024;
/// One region: header and file.
pub const REGION: usize = SLOT_FILE_BYTES + SLOT_HEADER_BYTES;

static REGIONS: SlotRegions<REGION> = SlotRegions::new();

/// Both regions, once per boot.
pub fn take() -> Option<(&'static mut [u8], &'static mut [u8])> {
    REGIONS.take()
}
