//! Seeded random numbers, the same construction as the project's `rng`
//! module: xoshiro256++ seeded from (seed, stream) through SplitMix64, so each
//! Monte-Carlo repetition and each consumer within it has its own stream and
//! nothing is global.

use rand::SeedableRng;

/// The generator used throughout.
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;

/// A generator for consumer `stream` of a run seeded with `seed`.
pub fn stream(seed: u64, stream: u64) -> SimRng {
    SimRng::seed_from_u64(splitmix64(
        seed ^ splitmix64(stream.wrapping_add(0x9E37_79B9_7F4A_7C15)),
    ))
}

/// SplitMix64 finaliser (Steele, Lea & Flood 2014).
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
