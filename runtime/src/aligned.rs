//! Owned byte buffers whose start is 8-byte aligned (`std` only).
//!
//! A policy file's values are borrowed in place as `&[f32]`, so [`crate::Mlp`] and the weights of a
//! decoded `dex_policy::PolicyView` need the file's bytes at an aligned address (4 bytes for the
//! values; 8, like [`crate::slots::SLOT_ALIGN`], here). Bytes read from disk or a socket, or embedded
//! with `include_bytes!`, carry no such guarantee: host programs copy them once with
//! [`aligned_copy`] and keep the [`AlignedBytes`] for as long as a view or network borrows from them.
//! Firmware needs neither: its policy slots are flash regions at aligned addresses.

use std::vec::Vec;

/// An 8-byte-aligned copy of `bytes`, so a policy's values can be borrowed as `&[f32]`.
pub fn aligned_copy(bytes: &[u8]) -> AlignedBytes {
    let mut words = std::vec![0u64; bytes.len().div_ceil(8)];
    bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
    AlignedBytes {
        words,
        len: bytes.len(),
    }
}

/// Owned bytes whose start is 8-byte aligned (made by [`aligned_copy`]).
#[derive(Debug, Clone)]
pub struct AlignedBytes {
    words: Vec<u64>,
    len: usize,
}

impl AlignedBytes {
    /// The bytes, starting at an 8-byte-aligned address.
    pub fn as_bytes(&self) -> &[u8] {
        let all: &[u8] = bytemuck::cast_slice(&self.words);
        &all[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use std::vec::Vec;

    use super::aligned_copy;

    #[test]
    fn copy_is_aligned_and_equal() {
        for len in [0usize, 1, 7, 8, 9, 33] {
            let bytes: Vec<u8> = (0..len).map(|i| i as u8).collect();
            let copy = aligned_copy(&bytes);
            assert_eq!(copy.as_bytes(), &bytes[..]);
            assert_eq!(copy.as_bytes().as_ptr() as usize % 8, 0);
        }
    }
}
