//! Seeded random numbers, the same generator and stream derivation as the
//! root crate (`beliefbus::rng`), so both crates reproduce the same streams.

use rand::SeedableRng;

/// xoshiro256++: fast, portable output stream.
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;

/// A generator for the named consumer `stream` of a run seeded with `seed`
/// (stream id mixed by SplitMix64, so streams never coincide by accident).
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

/// A stream id from several indices (e.g. seed role, grid point, action).
pub fn mix(parts: &[u64]) -> u64 {
    parts
        .iter()
        .fold(0x6A09_E667_F3BC_C909, |h, &p| splitmix64(h ^ p))
}
