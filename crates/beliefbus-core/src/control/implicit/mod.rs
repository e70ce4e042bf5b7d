//! Implicit sampling (Morzfeld, "Implicit sampling for path integral control,
//! Monte Carlo localization and SLAM", paper 003 §2) and its use for
//! path-integral optimal control (§3). Model-agnostic: the same pieces serve
//! the controllers now and the implicit particle filters (MCL/SLAM) later.
//!
//! To draw weighted samples of p ∝ e^{−F}:
//! 1. minimise F (Newton with analytic gradient and Hessian, line search —
//!    [`newton`]) for μ = argmin F, φ = F(μ); factor H = ∇²F(μ) = L Lᵀ in
//!    band storage so path problems cost O(horizon) ([`banded`]);
//! 2. map ξ ~ N(0, I) to X by the linear map X = μ + L⁻ᵀξ with weight (6), or
//!    the random map X = μ + λ L⁻ᵀ ξ/|ξ| with the corrected Jacobian (erratum
//!    E1) ([`maps`]);
//! 3. keep the weights in the log domain, normalise, compute ESS ([`weights`]).
//!
//! [`path`] builds the path functional F of eq. (15) (errata E2–E6) for a
//! control-affine model and estimates ψ (eq. 16) and the optimal control
//! u = γ R⁻¹ Gᵀ ∂ₓ log ψ (eq. 10, erratum E4).

pub mod banded;
pub mod estimator;
pub mod maps;
pub mod newton;
pub mod path;
pub use crate::math::{truncnorm, weights};

pub use banded::{NotPositiveDefinite, SymBand};
pub use estimator::{
    Estimate, EstimateError, EstimatorOptions, GateMode, GradientMethod, MapKind, PathSampler,
};
pub use maps::{linear_map, linear_map_log_weight, MapError, RandomMapSample, RandomMapWorkspace};
pub use newton::{NewtonError, NewtonOptions, NewtonResult, NewtonWorkspace, Objective};
pub use path::{DiagonalQuadraticCost, Gate, PathCost, PathFunctional, PathSetup};
