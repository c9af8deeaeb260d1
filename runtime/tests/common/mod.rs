//! Helpers shared by the runtime's slot and program-download tests.

#![allow(dead_code)]

/// Bytes of each policy slot region in the tests.
pub const REGION: usize = 16 * 1024;

/// Two 8-byte aligned regions of [`REGION`] bytes (backed by `u64`s).
pub fn regions() -> (Vec<u64>, Vec<u64>) {
    (vec![0u64; REGION / 8], vec![0u64; REGION / 8])
}

/// A region's bytes.
pub fn bytes(r: &mut [u64]) -> &mut [u8] {
    bytemuck::cast_slice_mut(r)
}
