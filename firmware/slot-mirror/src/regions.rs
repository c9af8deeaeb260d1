//! The two slot regions in RAM (`.bss`), handed out once per boot: where the runtime's
//! `PolicySlots` keeps the A/B files (the golden firmware's slot phase reads them as stand-ins
//! for flash; the node mirrors them into NorFlash with [`crate::SlotMirror`]).

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, Ordering};

/// One region of `N` bytes, 8-byte aligned (the policy file is read in place as f32 words).
#[repr(C, align(8))]
struct Region<const N: usize>(UnsafeCell<[u8; N]>);

/// Two regions of `N` bytes each (a slot header and the largest policy file a slot takes), meant
/// for a `static`: `static REGIONS: SlotRegions<N> = SlotRegions::new();`.
pub struct SlotRegions<const N: usize> {
    regions: [Region<N>; 2],
    taken: AtomicBool,
}

// SAFETY: the regions are only reached through `take`, which hands them out once.
unsafe impl<const N: usize> Sync for SlotRegions<N> {}

impl<const N: usize> SlotRegions<N> {
    /// Both regions zeroed (in `.bss`: erased at boot).
    #[allow(clippy::new_without_default)] // a `static` needs a `const fn`
    pub const fn new() -> Self {
        SlotRegions {
            regions: [
                Region(UnsafeCell::new([0; N])),
                Region(UnsafeCell::new([0; N])),
            ],
            taken: AtomicBool::new(false),
        }
    }

    /// Both regions, the first call only; `None` after.
    #[allow(clippy::mut_from_ref)] // interior mutability, handed out once: `taken` guards it
    pub fn take(&'static self) -> Option<(&'static mut [u8], &'static mut [u8])> {
        if self.taken.swap(true, Ordering::AcqRel) {
            return None;
        }
        let [a, b] = &self.regions;
        // SAFETY: `taken` lets this run once, so these are the only references to the regions.
        Some(unsafe { (&mut *a.0.get(), &mut *b.0.get()) })
    }
}
