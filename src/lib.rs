//! beliefbus: real-time estimation and control over zero-copy shared memory.
//!
//! The library holds everything but the thin `main`s of the stage executables:
//! models ([`model`]), Markov-chain approximations ([`chain`]), Bayes filters
//! ([`filter`]), controllers ([`control`]), the scenario plug-in API and its
//! registry ([`scenario`]), all iceoryx2 code ([`ipc`]), real-time plumbing
//! ([`rt`]), the pipeline configuration ([`config`]), the stage loops
//! ([`stage`]), launcher/supervisor/report ([`pipeline`]), the command line
//! ([`cli`]) and the paper reproductions ([`experiments`]).
//!
//! Conventions used across the crate:
//! - state vectors are `&[f64]` of the model's state dimension; matrices are
//!   flat `&[f64]` in **column-major** order (nalgebra's), so
//!   `DMatrixView::from_slice(m, rows, cols)` reads them without copying;
//! - time is `f64` seconds inside algorithms, `u64` CLOCK_MONOTONIC
//!   nanoseconds on the wire;
//! - every random draw takes an explicit [`rng::SimRng`] seeded from config.

pub mod belief;
pub mod chain;
pub mod cli;
pub mod config;
pub mod control;
pub mod experiments;
pub mod filter;
pub mod ipc;
pub mod latency;
pub mod model;
pub mod pipeline;
pub mod rng;
pub mod rt;
pub mod scenario;
pub mod stage;

/// Largest state dimension any model may have (fixed-size messages and
/// stack buffers are sized by it).
pub const MAX_STATE: usize = 8;
/// Largest dimension of the Wiener process driving a model.
pub const MAX_NOISE: usize = 8;
/// Largest observation dimension.
pub const MAX_OBS: usize = 8;
/// Largest control dimension.
pub const MAX_CONTROL: usize = 4;
