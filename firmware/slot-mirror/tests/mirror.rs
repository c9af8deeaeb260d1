//! The slot mirror over the RAM-backed NorFlash: NOR semantics, load, and sync that rewrites only
//! a sector whose bytes differ.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_slot_mirror::{MirrorError, RamNorFlash, SlotMirror};
use embedded_storage::nor_flash::{NorFlash, NorFlashErrorKind, ReadNorFlash};

const SECTOR: usize = 1024;
const N: usize = 2 * SECTOR;

fn flash() -> RamNorFlash<SECTOR, N> {
    RamNorFlash::new(Box::leak(Box::new([0u8; N])))
}

#[test]
fn ram_flash_has_nor_semantics() {
    let mut f = flash();
    let mut b = [0u8; 4];
    f.read(0, &mut b).unwrap();
    assert_eq!(b, [0xFF; 4]); // erased
    f.write(0, &[0xF0, 0x0F, 0xAA, 0x55]).unwrap();
    f.write(0, &[0x3C, 0xFF, 0xFF, 0x00]).unwrap(); // a write only clears bits
    f.read(0, &mut b).unwrap();
    assert_eq!(b, [0x30, 0x0F, 0xAA, 0x00]);
    f.erase(0, SECTOR as u32).unwrap();
    f.read(0, &mut b).unwrap();
    assert_eq!(b, [0xFF; 4]);
    // Misaligned erase and out-of-bounds access are typed errors.
    assert_eq!(
        f.erase(1, SECTOR as u32).unwrap_err().0,
        NorFlashErrorKind::NotAligned
    );
    assert_eq!(
        f.write(N as u32, &[0]).unwrap_err().0,
        NorFlashErrorKind::OutOfBounds
    );
}

#[test]
fn sync_rewrites_only_a_changed_sector_and_load_reads_it_back() {
    let mut m = SlotMirror::new(flash(), [0, SECTOR as u32]);
    let mut a = vec![0u8; 600];
    let mut b = vec![7u8; 600];
    // Fresh flash differs from both regions: both written.
    assert!(m.sync(0, &a).unwrap());
    assert!(m.sync(1, &b).unwrap());
    // Unchanged: nothing written.
    assert!(!m.sync(0, &a).unwrap());
    assert!(!m.sync(1, &b).unwrap());
    // One byte of region 1 changes (past the first comparison chunk): only sector 1 rewritten.
    b[300] = 9;
    assert!(!m.sync(0, &a).unwrap());
    assert!(m.sync(1, &b).unwrap());
    // Load into cleared regions: the last synced bytes come back.
    let (want_a, want_b) = (a.clone(), b.clone());
    a.fill(0xEE);
    b.fill(0xEE);
    m.load([&mut a, &mut b]).unwrap();
    assert_eq!((a, b), (want_a, want_b));
}

#[test]
fn a_region_larger_than_a_sector_is_refused() {
    let mut m = SlotMirror::new(flash(), [0, SECTOR as u32]);
    let big = vec![0u8; SECTOR + 1];
    assert_eq!(m.sync(0, &big), Err(MirrorError::RegionTooLarge));
}
