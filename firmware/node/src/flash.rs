//! The NorFlash behind the slot mirror: RAM-backed under QEMU, the STM32F405's sectors 5 and 6
//! on a board.

use dex_slot_mirror::SlotMirror;

/// QEMU: a RAM-backed NorFlash of two sectors, each one region rounded up to 1 KiB.
#[cfg(feature = "qemu")]
pub type MirrorFlash = dex_slot_mirror::RamNorFlash<RAM_SECTOR, { 2 * RAM_SECTOR }>;

/// QEMU's RAM-backed sector: one region rounded up to 1 KiB.
#[cfg(feature = "qemu")]
pub const RAM_SECTOR: usize = crate::regions::REGION.div_ceil(1024) * 1024;

/// Board: the MCU's flash, unlocked for each operation.
#[cfg(not(feature = "qemu"))]
pub type MirrorFlash = BoardFlash;

/// The mirror over the target's NorFlash.
pub fn mirror(flash: stm32f4xx_hal::pac::FLASH) -> Option<SlotMirror<MirrorFlash>> {
    #[cfg(feature = "qemu")]
    {
        use core::cell::UnsafeCell;
        use core::sync::atomic::{AtomicBool, Ordering};
        struct Mem(UnsafeCell<[u8; 2 * RAM_SECTOR]>);
        // SAFETY: reached once, through TAKEN.
        unsafe impl Sync for Mem {}
        static MEM: Mem = Mem(UnsafeCell::new([0; 2 * RAM_SECTOR]));
        static TAKEN: AtomicBool = AtomicBool::new(false);
        let _ = flash;
        if TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        // SAFETY: `TAKEN` lets this run once: the only reference to MEM.
        let mem = unsafe { &mut *MEM.0.get() };
        Some(SlotMirror::new(
            dex_slot_mirror::RamNorFlash::new(mem),
            [0, RAM_SECTOR as u32],
        ))
    }
    #[cfg(not(feature = "qemu"))]
    {
        Some(SlotMirror::new(
            BoardFlash(stm32f4xx_hal::flash::LockedFlash::new(flash)),
            [SECTOR5_OFFSET, SECTOR6_OFFSET],
        ))
    }
}

/// Offset of sector 5 (0x0802_0000) from the start of flash.
#[cfg(not(feature = "qemu"))]
const SECTOR5_OFFSET: u32 = 0x2_0000;
/// Offset of sector 6 (0x0804_0000).
#[cfg(not(feature = "qemu"))]
const SECTOR6_OFFSET: u32 = 0x4_0000;

/// The STM32F4 flash as one NorFlash: unlocked for each erase or write, locked again after.
#[cfg(not(feature = "qemu"))]
pub struct BoardFlash(stm32f4xx_hal::flash::LockedFlash);

#[cfg(not(feature = "qemu"))]
impl core::fmt::Debug for BoardFlash {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("BoardFlash")
    }
}

#[cfg(not(feature = "qemu"))]
mod board_impl {
    use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
    use stm32f4xx_hal::flash::{Error, FlashExt, UnlockedFlash};

    use super::BoardFlash;

    impl ErrorType for BoardFlash {
        type Error = Error;
    }

    impl ReadNorFlash for BoardFlash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
            ReadNorFlash::read(&mut self.0, offset, bytes)
        }

        fn capacity(&self) -> usize {
            ReadNorFlash::capacity(&self.0)
        }
    }

    impl NorFlash for BoardFlash {
        const WRITE_SIZE: usize = <UnlockedFlash<'static> as NorFlash>::WRITE_SIZE;
        const ERASE_SIZE: usize = <UnlockedFlash<'static> as NorFlash>::ERASE_SIZE;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
            NorFlash::erase(&mut self.0.unlocked(), from, to)
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
            NorFlash::write(&mut self.0.unlocked(), offset, bytes)
        }
    }
}
