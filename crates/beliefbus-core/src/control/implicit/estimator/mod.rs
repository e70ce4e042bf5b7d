//! ψ and the optimal control by implicit sampling (paper 003 §3, eq. 16 and
//! eq. 10 with errata E4/E6):
//!
//! ```text
//! ψ(x,t) ≈ C_n · Σ_c e^{−φ_c} (2π)^{N/2} E_ξ[w_c(ξ)],   C_n = Δt^{−N/2} (det Σ_b)^{−n/2} J_z
//! u(x,t) = γ R⁻¹ Gᵀ ∂ₓ log ψ(x,t)
//! ```
//!
//! The sum runs over *components* c: one per initial state (the belief mean,
//! or draws from the belief, ψ̄ = (1/K) Σ_k ψ(x_k)) and per basin of F (one
//! per slit of a [`Gate`], each found by a constrained minimisation: the
//! unconstrained minimiser if it lies in the slit, otherwise the minimiser
//! with the gated coordinate pinned at the nearer slit edge — exact for
//! convex F). Every component uses the same reference draws ξ (common random
//! numbers), optionally antithetic (ξ, −ξ), which makes the linear-quadratic
//! case exact for any number of samples.
//!
//! Two ways to get ∂ₓ log ψ along the columns g_j of G:
//! - [`GradientMethod::FiniteDifference`] — the paper's: re-minimise and
//!   re-sample with the same ξ at x ± h g_j, central differences of log ψ
//!   (2p extra solves per component);
//! - [`GradientMethod::Analytic`] — the exact derivative of the linear-map
//!   estimator with the proposal centre moving as μ(x) (implicit function
//!   theorem, δμ = −H⁻¹ ∂²F/∂z∂x · δx) and L held fixed:
//!   `∂ log ψ̂ = −Σ_{c,k} W_{c,k} [∂ₓF(X_{c,k})·δx + ∇_z F(X_{c,k})·δμ_c]`,
//!   with the normalised weights W. It is exact whenever ∇²F does not depend
//!   on x (linear drift, quadratic costs), costs one banded solve per
//!   direction instead of a minimisation, and with M = 0 samples it reduces
//!   to the Laplace (most-likely-path) control −γR⁻¹Gᵀ∂ₓF(μ).
//!
//! [`Gate`]: super::path::Gate

mod components;
mod estimate;
mod sampler;
#[cfg(test)]
mod tests;

pub use sampler::PathSampler;

use super::newton::{NewtonError, NewtonOptions};
use crate::MAX_CONTROL;

/// How ∂ₓ log ψ is computed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GradientMethod {
    /// Exact derivative of the linear-map estimator (see the module doc).
    Analytic,
    /// Central differences with step `h` and common random numbers.
    FiniteDifference { h: f64 },
    /// The likelihood-ratio (score) form ∂ₓ log ψ = −E_p[∂ₓF(Z; x)]
    /// estimated with the implicit-sampling weights at fixed samples:
    /// `∂ log ψ̂ = −Σ W_{c,k} ∂ₓF(X_{c,k})·δx`. For a control direction only
    /// the first K+1 steps of F depend on x, and to leading order in Δt the
    /// term is the first noise increment, u Δt ≈ B⁻¹ E_w[r₁] (the
    /// path-integral identity u dt = E_w[G dW₀]). No solve per direction
    /// and one value pass (not a gradient pass) per sample; consistent as
    /// M → ∞ (the analytic form is the exact derivative of the M-sample
    /// estimator), equal to it at M = 0 (envelope theorem) and exact for
    /// linear-quadratic problems with antithetic pairs.
    LikelihoodRatio,
}

/// Which map solves F(X) − φ = ½ξᵀξ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapKind {
    /// X = μ + L⁻ᵀξ, weight (6).
    Linear,
    /// X = μ + λ L⁻ᵀ ξ/|ξ|, Jacobian weight (E1).
    Random,
}

/// How a [`Gate`](super::path::Gate)'s basins are used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateMode {
    /// Every basin, each sample weighted by (6) and by its slit's indicator.
    AllBasins,
    /// The paper's §3.1 recipe: only the basin of smallest φ, weight 1/det L
    /// times the fraction of samples passing any slit (no e^{F̂−F} factor).
    SmallestBasin,
}

/// How samples of a gated basin are generated (linear map, analytic gradient).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateSampling {
    /// Draw the gated coordinate δ = X_k − μ_k from its Laplace marginal
    /// restricted to the slit, q(δ) ∝ e^{−g_k δ − δ²/(2s²)} (s² = (H⁻¹)_kk,
    /// g_k = ∂F/∂z_k(μ), non-zero at a pinned minimum), by its inverse CDF
    /// at stratified levels, and the other coordinates from the Gaussian
    /// N(μ, H⁻¹) conditioned on it; weight e^{−F}/q. Every sample passes
    /// the wall, and for quadratic F every weight is equal.
    Marginal,
    /// The plain linear map around the (constrained) minimum, samples
    /// outside the slit get weight 0 (about half of them).
    Rejection,
}

/// Settings of one estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorOptions {
    /// Samples M per component (0: Laplace approximation at the mode).
    pub samples: usize,
    /// Use antithetic pairs (ξ, −ξ).
    pub antithetic: bool,
    pub map: MapKind,
    pub gradient: GradientMethod,
    pub gate_mode: GateMode,
    /// Used with a gate, the linear map, all basins and the analytic gradient.
    pub gate_sampling: GateSampling,
    pub newton: NewtonOptions,
}

impl Default for EstimatorOptions {
    fn default() -> Self {
        Self {
            samples: 16,
            antithetic: true,
            map: MapKind::Linear,
            gradient: GradientMethod::Analytic,
            gate_mode: GateMode::AllBasins,
            gate_sampling: GateSampling::Marginal,
            newton: NewtonOptions::default(),
        }
    }
}

/// Why an estimate failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    #[error("minimisation failed: {0}")]
    Newton(#[from] NewtonError),
    #[error("no sample has positive weight (every path hits the wall)")]
    NoMass,
    #[error("{0}")]
    Unsupported(&'static str),
    #[error("problem exceeds the sampler's capacity: {0}")]
    Capacity(&'static str),
}

/// Result of one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// log ψ̄ including every constant (comparable with an analytic ψ).
    pub log_psi: f64,
    /// Gᵀ ∂ₓ log ψ̄.
    pub grad_g: [f64; MAX_CONTROL],
    /// u = γ R⁻¹ Gᵀ ∂ₓ log ψ̄.
    pub u: [f64; MAX_CONTROL],
    /// Smallest φ over the components.
    pub phi: f64,
    /// Effective sample size of all weights together.
    pub ess: f64,
    /// Samples evaluated (all components, not counting FD re-evaluations).
    pub samples: usize,
    /// Fraction of samples with positive weight (paths through the gate).
    pub pass_fraction: f64,
    /// Newton iterations of all minimisations.
    pub newton_iterations: usize,
    /// Components (initial states × basins) used.
    pub components: usize,
}
