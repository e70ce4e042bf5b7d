//! Monte Carlo localization with implicit sampling, after Morzfeld,
//! "Implicit sampling for path integral control, Monte Carlo localization
//! and SLAM" (paper 003 §4.1 and appendix), beside standard MCL, on a
//! synthetic car park driven by the Victoria Park odometry.
//!
//! - [`geometry`], [`vehicle`], [`laser`]: planar poses, the Ute kinematics
//!   with the corrected laser-point model (E10), the range/bearing laser
//!   model with its analytic gradient and corrected Hessian (E12);
//! - [`victoria`]: the reader of the Victoria Park odometry and scan times;
//! - [`carpark`]: the synthetic car park (true path, landmarks, scans, gaps);
//! - [`mcl`]: implicit MCL and standard MCL on the same models;
//! - [`slam`]: implicit SLAM, FastSLAM 1.0/2.0 and EKF-SLAM with one data association;
//! - [`experiments`]: the paper's Table 5 as a library function.
//!
//! Pure computation apart from reading the data files: no global state;
//! every random draw comes from a [`beliefbus_core::rng::SimRng`] passed in.

pub mod carpark;
pub mod error;
pub mod experiments;
pub mod geometry;
pub mod laser;
pub mod mcl;
pub mod slam;
pub mod vehicle;
pub mod victoria;

pub use error::LocalizationError;
