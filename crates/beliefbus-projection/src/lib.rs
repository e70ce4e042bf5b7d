//! Solving continuous-state POMDPs by density projection (Zhou, Fu & Marcus,
//! "Solving continuous-state POMDPs via density projection").
//!
//! The belief b_k is projected onto an exponential family
//! Ω = {f(x, θ) = exp(θᵀc(x) − φ(θ))} by minimising D_KL(b‖f), which is
//! moment matching of the sufficient statistics: E_b[c_j] = E_θ[c_j]
//! (paper eq. 9, §III). Three pieces follow from that:
//!
//! * [`ppf::ProjectionPf`]: the projection particle filter (§IV, the
//!   paper's Algorithm 4): predict, weight, project the *updated* weighted
//!   particles, resample from the continuous projected density. The belief
//!   carried between steps is only θ̂.
//! * [`mdp`] and [`build`]: the projected-belief MDP on a grid of projected
//!   parameters, its one-step costs and transitions estimated by Monte Carlo
//!   (§III, the paper's Algorithms 1–2), solved by value iteration
//!   (discounted) or relative value iteration (average cost).
//! * [`policy::GridPolicy`]: the solved policy as a table over the grid, saved
//!   with a key of the problem parameters so a stale file is refused, and
//!   evaluated on-line as projection + nearest-grid lookup.
//!
//! [`inventory`] is the paper's §VI benchmark and [`experiments`] reproduces
//! its Tables I and II. The crate is pure computation: generic over the small
//! model traits of [`model`], seeded RNG passed explicitly, no global state.

pub mod bootstrap;
pub mod build;
pub mod error;
pub mod experiments;
pub mod family;
pub mod gaussian;
pub mod grid;
pub mod inventory;
pub mod mdp;
pub mod model;
pub mod parallel;
pub mod policy;
pub mod ppf;
pub mod rng;
pub mod sde_pf;
pub mod solve;

pub use error::ProjectionError;
pub use family::ExpFamily;
pub use gaussian::{Gaussian, GaussianParams};
pub use grid::{Axis, ParamGrid};
pub use model::{FilterModel, Pomdp};
pub use policy::{GridPolicy, PolicyError, PolicyKey};
pub use ppf::ProjectionPf;
pub use sde_pf::SdeProjectionPf;
