//! Seeded random numbers: the workspace's generator and stream derivation
//! (`beliefbus_core::rng`), plus a stream id made of several indices.

pub use beliefbus_core::rng::{splitmix64, stream, SimRng};

/// A stream id from several indices (e.g. seed role, grid point, action).
pub fn mix(parts: &[u64]) -> u64 {
    parts
        .iter()
        .fold(0x6A09_E667_F3BC_C909, |h, &p| splitmix64(h ^ p))
}
