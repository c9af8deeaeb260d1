//! `dex-slot-mirror`: the A/B policy slots' persistent copy behind `embedded-storage`'s [`NorFlash`].
//!
//! The runtime's [`dex_runtime::PolicySlots`] reads and writes two byte-addressable regions in
//! RAM (the policy is read in place by the evaluator). This module keeps each region's persistent
//! copy in a NorFlash sector: at boot [`SlotMirror::load`] reads both sectors into the regions
//! (before `PolicySlots::mount`); after every frame the node calls [`SlotMirror::sync`], which
//! compares each region with its sector and rewrites (erase + program) only a sector whose bytes
//! differ. A transfer writes only the inactive region, so only the inactive sector is ever
//! erased while a policy runs: a power cut mid-write loses the new file, never the active one.
//!
//! The board build uses stm32f4xx-hal's `UnlockedFlash` (sectors 5 and 6, 128 KiB each); the
//! QEMU build [`RamNorFlash`], because QEMU models the STM32F405's flash as ROM and ignores the
//! flash controller.
#![no_std]

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};

pub mod regions;
pub use regions::SlotRegions;

/// Bytes compared per step of [`SlotMirror::sync`].
const CHUNK: usize = 256;

pub use ram::{RamFlashError, RamNorFlash};

mod ram {
    use embedded_storage::nor_flash::{
        ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash, check_erase,
        check_read, check_write,
    };

    /// NOR flash semantics over a RAM buffer: erase sets a sector to 0xFF, a write can only clear
    /// bits (it ANDs), reads are plain. For targets whose flash cannot be written (QEMU).
    #[derive(Debug)]
    pub struct RamNorFlash<const SECTOR: usize, const N: usize> {
        mem: &'static mut [u8; N],
    }

    impl<const SECTOR: usize, const N: usize> RamNorFlash<SECTOR, N> {
        /// Over `mem` (its length a multiple of `SECTOR`), erased.
        pub fn new(mem: &'static mut [u8; N]) -> Self {
            mem.fill(0xFF);
            RamNorFlash { mem }
        }
    }

    /// Errors of [`RamNorFlash`]: the embedded-storage kinds (alignment, bounds).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub struct RamFlashError(
        /// What went wrong.
        pub NorFlashErrorKind,
    );

    impl NorFlashError for RamFlashError {
        fn kind(&self) -> NorFlashErrorKind {
            self.0
        }
    }

    impl<const SECTOR: usize, const N: usize> ErrorType for RamNorFlash<SECTOR, N> {
        type Error = RamFlashError;
    }

    impl<const SECTOR: usize, const N: usize> ReadNorFlash for RamNorFlash<SECTOR, N> {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            check_read(self, offset, bytes.len()).map_err(RamFlashError)?;
            let start = offset as usize;
            bytes.copy_from_slice(&self.mem[start..start + bytes.len()]);
            Ok(())
        }

        fn capacity(&self) -> usize {
            N
        }
    }

    impl<const SECTOR: usize, const N: usize> NorFlash for RamNorFlash<SECTOR, N> {
        const WRITE_SIZE: usize = 1;
        const ERASE_SIZE: usize = SECTOR;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            check_erase(self, from, to).map_err(RamFlashError)?;
            self.mem[from as usize..to as usize].fill(0xFF);
            Ok(())
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            check_write(self, offset, bytes.len()).map_err(RamFlashError)?;
            let start = offset as usize;
            for (cell, b) in self.mem[start..start + bytes.len()].iter_mut().zip(bytes) {
                *cell &= *b;
            }
            Ok(())
        }
    }
}

/// Why a mirror operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MirrorError {
    /// The NorFlash refused a read, erase or write.
    Flash(NorFlashErrorKind),
    /// A region is longer than its sector.
    RegionTooLarge,
}

/// Two slot regions' persistent copies: sector offsets `bases[i]` (erase-aligned) in `flash`.
#[derive(Debug)]
pub struct SlotMirror<F> {
    flash: F,
    bases: [u32; 2],
}

impl<F: NorFlash> SlotMirror<F> {
    /// Mirrors region 0 at `bases[0]` and region 1 at `bases[1]` of `flash`.
    pub fn new(flash: F, bases: [u32; 2]) -> Self {
        SlotMirror { flash, bases }
    }

    fn check(len: usize) -> Result<(), MirrorError> {
        if len > F::ERASE_SIZE {
            Err(MirrorError::RegionTooLarge)
        } else {
            Ok(())
        }
    }

    /// Reads both sectors into the regions (at boot, before mounting the slots).
    pub fn load(&mut self, regions: [&mut [u8]; 2]) -> Result<(), MirrorError> {
        for (base, region) in self.bases.into_iter().zip(regions) {
            Self::check(region.len())?;
            self.flash
                .read(base, region)
                .map_err(|e| MirrorError::Flash(e.kind()))?;
        }
        Ok(())
    }

    /// Rewrites the sector of region `index` if its bytes differ from `region`; returns whether
    /// it wrote.
    pub fn sync(&mut self, index: usize, region: &[u8]) -> Result<bool, MirrorError> {
        Self::check(region.len())?;
        let base = self.bases[index % 2];
        let mut chunk = [0u8; CHUNK];
        let mut same = true;
        for (k, want) in region.chunks(CHUNK).enumerate() {
            let got = &mut chunk[..want.len()];
            self.flash
                .read(base + (k * CHUNK) as u32, got)
                .map_err(|e| MirrorError::Flash(e.kind()))?;
            if got != want {
                same = false;
                break;
            }
        }
        if same {
            return Ok(false);
        }
        let err = |e: F::Error| MirrorError::Flash(e.kind());
        self.flash
            .erase(base, base + F::ERASE_SIZE as u32)
            .map_err(err)?;
        self.flash.write(base, region).map_err(err)?;
        Ok(true)
    }
}
