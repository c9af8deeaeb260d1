//! Episode seeds: episode `index` of an evaluation seeded with `seed` starts from the start state
//! drawn with [`episode_seed`]`(seed, index)`, in every program that runs episodes (`trainer eval`
//! and the trainer's evaluations, `hil-sim run` and `hil-sim plant`, the Python package's
//! `dexstack.episode_seed`), so that they see the same starts for the same seed.
//!
//! It is defined here, below the environment, because `hil-sim` draws its synthetic plant's
//! episodes from it in builds without MuJoCo. The seed ranges the project's evaluations use are
//! named in `dex_env::seeds`.

/// Seed of episode `index` of an evaluation seeded with `seed` (SplitMix64's mix of both).
///
/// Its values are fixed: the success rates recorded for the shipped policies and in the docs are
/// over the starts it draws.
pub fn episode_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::episode_seed;

    #[test]
    fn episode_seeds_differ_and_repeat() {
        assert_eq!(episode_seed(1, 5), episode_seed(1, 5));
        assert_ne!(episode_seed(1, 5), episode_seed(1, 6));
        assert_ne!(episode_seed(1, 5), episode_seed(2, 5));
    }

    #[test]
    fn episode_seeds_keep_their_values() {
        assert_eq!(episode_seed(1_000_000, 0), 7_132_602_722_347_131_734);
        assert_eq!(episode_seed(7, 3), 16_731_224_329_868_871_185);
        assert_eq!(episode_seed(0, 0), 0);
    }
}
