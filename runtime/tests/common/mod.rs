//! Helpers shared by the runtime's integration tests (slots, program download, kinematics, envelope).

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

/// A seeded generator of test values (splitmix64).
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 bits.
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1), 24 bits.
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// `N` angles uniform in [-r, r].
    pub fn angles<const N: usize>(&mut self, r: f32) -> [f32; N] {
        core::array::from_fn(|_| (self.unit() * 2.0 - 1.0) * r)
    }
}
