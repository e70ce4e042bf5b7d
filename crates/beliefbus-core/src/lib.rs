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
//!
//! A filter on a model in a few lines — here a particle filter checked
//! against the exact Kalman filter on a linear-Gaussian SDE (a user model
//! implements [`model::SdeModel`] instead; see
//! `examples/filter_your_model.rs`):
//!
//! ```
//! use beliefbus_core::{belief::Gaussian, filter::{kalman::Kalman, pf::PfConfig, BayesFilter}};
//! use beliefbus_core::model::{linear::LinearSde, simulate_observation, Bounds, Measurement};
//! use nalgebra::DMatrix;
//! // dx = -x dt + 0.5 dw, y = x + N(0, 0.2²)
//! let m = |v: f64| DMatrix::from_element(1, 1, v);
//! let bounds = Bounds::new_box(&[-5.0], &[5.0]).unwrap();
//! let ou = LinearSde::new("ou", m(-1.0), DMatrix::zeros(1, 0), m(0.5), m(1.0), vec![0.2], bounds);
//! let prior = Gaussian::diagonal(&[0.0], &[1.0]);
//! let mut kf = Kalman::new(ou.clone(), &prior, 0.0).unwrap();
//! let cfg = PfConfig { particles: 4000, seed: 1, ..PfConfig::default() };
//! let mut pf = cfg.build(ou.clone(), &prior, 0.0).unwrap();
//! let (mut rng, mut y) = (beliefbus_core::rng::stream(1, 0), [0.0]);
//! for k in 1..=50 {
//!     let truth = [(k as f64 * 0.3).sin()];
//!     simulate_observation(&ou, &truth, &mut rng, &mut y);
//!     for f in [&mut kf as &mut dyn BayesFilter, &mut pf] {
//!         f.predict(k as f64 * 0.1, &[]).unwrap();
//!         f.update(&Measurement::full(&y)).unwrap();
//!     }
//!     // 4000 particles: the PF's mean within a few Monte Carlo s.e. of the exact one
//!     let (exact, sd) = (kf.belief().mean[0], kf.belief().cov[0].sqrt());
//!     assert!((pf.belief().mean[0] - exact).abs() < 0.1 * sd, "step {k}");
//! }
//! ```

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
