//! The path functional F of paper 003 eq. (15), with errata E2–E6, for a
//! control-affine model (see [`crate::model::affine`]):
//!
//! ```text
//! y₀ = x(t),  τ_i = t + iΔt,  r_i = P (y_i − y_{i−1} − f0(y_{i−1}) Δt)          (E5: f at i−1)
//! F(y₁..y_n) = Φ(y_n)/γ + Δt/(2γ) Σ_{i=1}^{n} [V(y_i) + V(y_{i−1})]              (E5: brackets)
//!            + ½ Σ_{i=1}^{n} r_iᵀ (Σ_b Δt)⁻¹ r_i
//! ψ(x, t) ≈ (2πΔt)^{−N/2} (det Σ_b)^{−n/2} J_z ∫ e^{−F} dz                     (E5/E6 normaliser)
//! ```
//!
//! Σ_b is the noise covariance on the noise-driven coordinates: Σ = GQQᵀGᵀ
//! for a [`PathStructure::Full`] model, BQQᵀBᵀ on the velocities of a
//! [`PathStructure::SecondOrder`] one (P selects those rows). The path
//! variables z are the noise-driven coordinates only:
//! - `Full`: z_i = y_i ∈ ℝᵐ, i = 1..n (N = mn, J_z = 1);
//! - `SecondOrder`: x = (q, v); with Euler, q_{i+1} = q_i + v_i Δt, so the
//!   velocities v₁..v_n are in one-to-one linear correspondence with the
//!   positions z_i = q_{i+1}, i = 1..n (N = pn). Using positions as variables
//!   keeps the Hessian banded (v_i = (q_{i+1} − q_i)/Δt is local) whereas
//!   positions as functions of velocities would make it dense; the constant
//!   Jacobian of the change of variables is J_z = Δt^{−N}.
//!
//! Every path point is an affine function of a few consecutive blocks of
//! the "extended" vector (prefix blocks fixed by x(t), then z), so the term
//! of step i couples (K+2) blocks and the Hessian has half-bandwidth
//! (K+2)·b − 1 (block-tridiagonal for `Full`, K = 0). Derivatives are
//! analytic: the model supplies ∂f0/∂x and the curvature Σ w_k ∇²f0_k, the
//! cost supplies ∇V, ∇²V, ∇Φ, ∇²Φ.
//!
//! The prefix gradient ∂F/∂x(t) (what [`PathFunctional::gradient_x`]
//! returns) is the x-derivative of F at fixed z, used for the analytic
//! control estimate (envelope theorem at μ).
//!
//! [`PathStructure::Full`]: crate::model::affine::PathStructure::Full
//! [`PathStructure::SecondOrder`]: crate::model::affine::PathStructure::SecondOrder

mod functional;
mod pass;
mod setup;
#[cfg(test)]
mod tests;

pub use crate::control::cost::DiagonalQuadraticCost;
pub use crate::model::path_cost::{Gate, PathCost, MAX_GATE_INTERVALS};
pub use functional::PathFunctional;
pub use setup::PathSetup;
