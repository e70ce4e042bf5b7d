//! beliefbus-core: the algorithms, pure and seeded (no I/O, no IPC): models
//! ([`model`]), Markov-chain approximations ([`chain`]), Bayes filters,
//! smoothers and decoders ([`filter`]), controllers ([`control`]), beliefs
//! ([`belief`]), the random-number streams ([`rng`]), the numerical
//! building blocks under them all ([`math`]) and the experiment report
//! every paper reproduction fills ([`report`]).
//!
//! Inside the crate, too, a module uses only the ones below it:
//! `math`, `rng` < `belief` < `model` < `chain`, `control` < `filter`.
//!
//! Conventions used across the workspace:
//! - state vectors are `&[f64]` of the model's state dimension; matrices are
//!   flat `&[f64]` in **column-major** order (nalgebra's), so
//!   `DMatrixView::from_slice(m, rows, cols)` reads them without copying;
//! - time is `f64` seconds inside algorithms, `u64` CLOCK_MONOTONIC
//!   nanoseconds on the wire;
//! - every random draw takes an explicit [`rng::SimRng`] seeded from config.

pub mod belief;
pub mod chain;
pub mod control;
pub mod experiment_params;
pub mod filter;
pub mod math;
pub mod model;
pub mod report;
pub mod rng;

/// Largest state dimension any model may have (fixed-size messages and
/// stack buffers are sized by it).
pub const MAX_STATE: usize = 8;
/// Largest dimension of the Wiener process driving a model.
pub const MAX_NOISE: usize = 8;
/// Largest observation dimension.
pub const MAX_OBS: usize = 8;
/// Largest control dimension.
pub const MAX_CONTROL: usize = 4;
