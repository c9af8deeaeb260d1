//! Policy flashing over CAN: the controller node's two policy slots.
//!
//! The transfer, verification, activation and roll-back are the runtime's
//! (`dex_runtime::slots`, served by `Controller::on_frame_slots`), the same code a
//! microcontroller runs; this module holds the node's storage for them: two fixed, 8-byte-aligned
//! regions allocated once when the node starts (standing for two flash sectors) and reused for
//! every flash, so memory stays bounded however often the node is flashed (`tests/flash_memory.rs`).
//!
//! Frames: requests on `0x600 + node`, responses on `0x580 + node` (the table in
//! `dex_runtime::slots` and `docs/sil.md`).

pub use dex_runtime::slots::{
    BLOCK_SEGMENTS, FLASH_REQUEST_BASE, FLASH_RESPONSE_BASE, FlashStatus, SLOT_HEADER_BYTES,
};

/// Largest policy file accepted into a slot.
pub const SLOT_CAPACITY: usize = 512 * 1024;

/// The node's slot storage: two regions of [`SLOT_HEADER_BYTES`] + [`SLOT_CAPACITY`] bytes.
#[derive(Debug)]
pub struct SlotStorage {
    regions: [Box<[u64]>; 2],
}

impl SlotStorage {
    /// Two erased (zeroed) regions.
    pub fn new() -> Self {
        let words = (SLOT_HEADER_BYTES + SLOT_CAPACITY).div_ceil(8);
        SlotStorage {
            regions: [
                vec![0u64; words].into_boxed_slice(),
                vec![0u64; words].into_boxed_slice(),
            ],
        }
    }

    /// Both regions as bytes (8-byte aligned), for `PolicySlots::mount`.
    pub fn regions(&mut self) -> (&mut [u8], &mut [u8]) {
        let [a, b] = &mut self.regions;
        (bytemuck::cast_slice_mut(a), bytemuck::cast_slice_mut(b))
    }

    /// Bytes held, both regions together.
    pub fn bytes(&self) -> usize {
        self.regions.iter().map(|r| r.len() * 8).sum()
    }
}

impl Default for SlotStorage {
    fn default() -> Self {
        Self::new()
    }
}
