//! A small, seedable, reproducible random number generator (xoshiro256++ seeded through SplitMix64).
//!
//! The learner never touches a thread-local or OS generator: every worker, environment and evaluation owns
//! an [`Rng`] derived from the run seed with [`Rng::derive`], so a run is a pure function of its seed (for
//! one worker). The state is four `u64`s, which checkpoints store and restore exactly.

/// Xoshiro256++ generator with Gaussian sampling (Marsaglia's polar method, spare value cached).
#[derive(Debug, Clone, PartialEq)]
pub struct Rng {
    s: [u64; 4],
    spare: Option<f64>,
}

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator seeded from one `u64` (any value, zero included, is fine).
    pub fn seed_from_u64(seed: u64) -> Self {
        let mut sm = seed;
        let s = [
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
        ];
        Rng { s, spare: None }
    }

    /// An independent stream for a purpose (`stream`, e.g. worker index) derived from a seed.
    pub fn derive(seed: u64, stream: u64) -> Self {
        let mut sm = seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        let mixed = splitmix64(&mut sm) ^ stream;
        Self::seed_from_u64(mixed)
    }

    /// The raw state (four words and the cached Gaussian), for checkpoints.
    pub fn state(&self) -> ([u64; 4], Option<f64>) {
        (self.s, self.spare)
    }

    /// Rebuilds a generator from [`Rng::state`]. An all-zero state (never produced by seeding) is
    /// replaced by the seed-0 state, because xoshiro would stay at zero forever.
    pub fn from_state(s: [u64; 4], spare: Option<f64>) -> Self {
        if s == [0; 4] {
            return Self::seed_from_u64(0);
        }
        Rng { s, spare }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let result = self.s[0]
            .wrapping_add(self.s[3])
            .rotate_left(23)
            .wrapping_add(self.s[0]);
        let t = self.s[1] << 17;
        self.s[2] ^= self.s[0];
        self.s[3] ^= self.s[1];
        self.s[1] ^= self.s[2];
        self.s[0] ^= self.s[3];
        self.s[2] ^= t;
        self.s[3] = self.s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn uniform_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform_f64() as f32
    }

    /// Uniform integer in [0, n); `n` must be positive (0 returns 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            return 0;
        }
        // Lemire's multiply-shift; the bias for n far below 2^64 is negligible for replay sampling.
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }

    /// Standard normal sample.
    pub fn normal_f64(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        loop {
            let u = 2.0 * self.uniform_f64() - 1.0;
            let v = 2.0 * self.uniform_f64() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let f = (-2.0 * s.ln() / s).sqrt();
                self.spare = Some(v * f);
                return u * f;
            }
        }
    }

    /// Normal sample with the given mean and standard deviation.
    pub fn normal(&mut self, mean: f32, std: f32) -> f32 {
        mean + std * self.normal_f64() as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproducible_and_restorable() {
        let mut a = Rng::seed_from_u64(7);
        let mut b = Rng::seed_from_u64(7);
        for _ in 0..10 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        let _ = a.normal_f64();
        let (s, spare) = a.state();
        let mut c = Rng::from_state(s, spare);
        for _ in 0..10 {
            assert_eq!(a.normal_f64().to_bits(), c.normal_f64().to_bits());
        }
        assert_ne!(Rng::derive(1, 0).next_u64(), Rng::derive(1, 1).next_u64());
    }

    #[test]
    fn moments_are_sane() {
        let mut r = Rng::seed_from_u64(3);
        let n = 20_000;
        let (mut m, mut m2, mut u) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let z = r.normal_f64();
            m += z;
            m2 += z * z;
            u += r.uniform_f64();
        }
        let n = f64::from(n);
        assert!((m / n).abs() < 0.03);
        assert!((m2 / n - 1.0).abs() < 0.05);
        assert!((u / n - 0.5).abs() < 0.02);
        assert!((0..1000).all(|_| r.below(5) < 5));
    }
}
