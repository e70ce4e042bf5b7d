//! Fast particle filters for change-point models, after Chen, Lai & Wu,
//! "Fast particle filters and their applications to adaptive control in
//! change-point ARX models and robotics" (2009), and Chen & Lai (2007).
//!
//! - [`meanshift`]: the normal mean-shift model, its fast Rao-Blackwellised
//!   filter (§3.2, §5.1), the exact run-length filter and a bootstrap PF;
//! - [`arx`]: the change-point ARX model (13), its filter with per-particle
//!   Kalman statistics (14)–(16), sliding-window and forgetting-factor least
//!   squares, and the adaptive control rules (18) and (20);
//! - [`resample`], [`weights`]: resampling schemes and log-domain weights;
//! - [`experiments`]: the paper's Tables 1–3 and the ARX studies as library
//!   functions returning rows beside the paper's.
//!
//! Pure computation: no I/O, no global state; every random draw comes from
//! a [`rng::SimRng`] passed in.

pub mod arx;
pub mod error;
pub mod experiments;
pub mod meanshift;
pub mod resample;
pub mod rng;
pub mod weights;

pub use error::ChangepointError;
