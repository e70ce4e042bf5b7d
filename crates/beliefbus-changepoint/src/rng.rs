//! Seeded random numbers: the workspace's generator and stream derivation
//! (`beliefbus_core::rng`), so each Monte-Carlo repetition and each consumer
//! within it has its own stream and nothing is global.

pub use beliefbus_core::rng::{splitmix64, stream, SimRng};
