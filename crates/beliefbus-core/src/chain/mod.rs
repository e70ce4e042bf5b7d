//! Markov-chain approximation of a diffusion by random sampling (thesis
//! ch. 2–3, paper 001 §IV–V): a chain M_n = (S_n, P_n, T_n) on sampled states
//! that is locally consistent with
//!
//! ```text
//! dx = f(x, u₀) dt + F(x) dw        (eq. 2.1; u₀ the chain's reference control)
//! E[Δξ | z] / Δt(z) → f(z),   Cov[Δξ | z] / Δt(z) → F Fᵀ(z),   Δt(z) → 0   (eq. 2.5–2.7)
//! ```
//!
//! Procedures (thesis §2.4.1) and where they live:
//! - `Sample` — [`sample::Sampler`] (uniform on S, or concentrated around a
//!   Gaussian belief mixed with uniform); the prior-predictive placement of
//!   §3.3.3 with weighted sample elimination — [`placement`];
//! - `Near` — [`NearRule`] on the k-d tree of [`index::SpatialIndex`]:
//!   the papers' radius r = γ(log n/n)^{1/d}, or k = ⌈c log n⌉ nearest
//!   (k-PRM*), r then being the distance to the k-th neighbour;
//!   under incremental construction the k-NN Near lists are kept exact by
//!   reverse queries on [`knn_tree::KnnTree`];
//! - `ComputeHoldingTime`, `ComputeTransProb` — [`kernel`] (Gaussian or
//!   moment-matching "LP" kernel);
//! - `ConnectState`, batch Alg. 2.1, incremental Alg. 2.3 — [`Chain`];
//! - time-equalised chain (eq. 3.8–3.9) with exponential backup —
//!   [`equalize`];
//! - local-consistency diagnostics (eq. 2.6–2.7) — [`diagnostics`];
//! - singular F Fᵀ with noise-free coordinates: the degenerate
//!   moment-matching kernel — [`degenerate`] — and the anisotropic metric
//!   that makes it consistent — [`metric`];
//! - flat CSR storage and snapshot views — [`storage`].

pub mod build;
pub mod degenerate;
pub mod diagnostics;
pub mod equalize;
pub mod frame;
pub mod index;
pub mod kernel;
pub mod knn_tree;
pub mod metric;
#[cfg(test)]
mod nn_timing_tests;
pub use crate::math::linalg;
pub mod nnls;
pub mod order;
pub mod placement;
pub mod prefetch;
pub mod retire;
pub use crate::model::sample;
pub mod snapshot;
pub mod steady;
pub mod storage;

pub use build::{BatchBuild, Chain, ChainStats};
pub use diagnostics::{ConsistencyReport, RowReport, StateConsistency};
pub use equalize::{PropagationKernel, TimeEqualized};
pub use kernel::{KernelKind, KernelOutcome};
pub use sample::Sampler;
pub use storage::{ChainView, ViewError};

use crate::MAX_CONTROL;

/// The `Near` rule.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NearRule {
    /// All states within r = γ (log n / n)^{1/d} (thesis, paper 001). The
    /// proof's γ > 2(2μ(S))^{1/d} ([`gamma_min`]) gives hundreds to
    /// thousands of neighbours in 4-D; γ is free here and the realised mean
    /// out-degree is reported by [`Chain::mean_out_degree`].
    Radius { gamma: f64 },
    /// The k = ⌈c log n⌉ nearest states (k-PRM*, Karaman & Frazzoli 2011),
    /// floored at `ChainConfig::min_neighbours`; r is the distance to the
    /// k-th neighbour (a local radius that adapts to the sampling density).
    Knn { c: f64 },
}

/// The proof's bound γ > 2 (2 μ(S))^{1/d} (thesis Theorem 2.4).
pub fn gamma_min(volume: f64, dim: usize) -> f64 {
    2.0 * (2.0 * volume).powf(1.0 / dim as f64)
}

/// Construction parameters of a chain.
#[derive(Clone, Debug, PartialEq)]
pub struct ChainConfig {
    pub near: NearRule,
    /// Floor on the neighbour count of the k-NN form (log n is small for
    /// small n; the moment-matching kernel needs at least as many
    /// neighbours as moment equations, 1 + d + d(d+1)/2).
    pub min_neighbours: usize,
    /// Radius form only: keep at most this many nearest neighbours.
    pub max_degree: Option<usize>,
    pub kernel: KernelKind,
    /// κ_F in Δt = r²/(κ_F ‖FFᵀ‖ + κ_f r ‖f‖) (thesis: 1).
    pub kappa_diffusion: f64,
    /// κ_f (thesis: 1).
    pub kappa_drift: f64,
    /// The control u₀ held while building (length = model control dim; the
    /// thesis builds uncontrolled chains, u₀ = 0).
    pub control: [f64; MAX_CONTROL],
    /// Advected ("semi-Lagrangian") construction with a common holding time
    /// τ (see [`build`]): Δt(z) = τ for every state, Near is taken around
    /// the advected point z + m(z), m(z) the RK4 flow displacement over τ,
    /// and the kernel matches mean m(z) and covariance F Fᵀ τ. `None`: the
    /// thesis's per-state Δt(z) and Near around z.
    pub step: Option<f64>,
}

impl ChainConfig {
    /// The thesis's construction: Gaussian kernel, κ_F = κ_f = 1, with the
    /// k-NN Near rule (c = 1.5).
    pub fn gaussian(dim: usize) -> Self {
        Self {
            near: NearRule::Knn { c: 1.5 },
            min_neighbours: moment_equations(dim) + 1,
            max_degree: None,
            kernel: KernelKind::Gaussian,
            kappa_diffusion: 1.0,
            kappa_drift: 1.0,
            control: [0.0; MAX_CONTROL],
            step: None,
        }
    }

    /// Moment-matching kernel. κ_F = 2(d + 2): neighbours uniform in a ball
    /// of radius r have E‖Δz‖² = d r²/(d + 2), so the required second moment
    /// d r²/κ_F is half of what the neighbours offer (feasible, p₀ ≈ ½);
    /// κ_f = 2: the mean jump |f|Δt ≤ r/2, about a neighbour distance, which
    /// keeps numerical diffusion low on drift-dominated states.
    pub fn moment_matched(dim: usize) -> Self {
        Self {
            kernel: KernelKind::MomentMatched,
            kappa_diffusion: 2.0 * (dim as f64 + 2.0),
            kappa_drift: 2.0,
            ..Self::gaussian(dim)
        }
    }

    /// Advected construction with common holding time τ (use the filter's
    /// observation period or a power-of-two fraction of it).
    pub fn with_step(mut self, tau: f64) -> Self {
        self.step = Some(tau);
        self
    }

    /// Replace the Near rule.
    pub fn with_near(mut self, near: NearRule) -> Self {
        self.near = near;
        self
    }

    /// Check the parameters.
    pub fn validate(&self) -> Result<(), ChainError> {
        let ok = match self.near {
            NearRule::Radius { gamma } => gamma.is_finite() && gamma > 0.0,
            NearRule::Knn { c } => c.is_finite() && c > 0.0,
        };
        if !ok {
            return Err(ChainError::Config(
                "Near constant must be positive and finite",
            ));
        }
        if !(self.kappa_diffusion.is_finite()
            && self.kappa_diffusion > 0.0
            && self.kappa_drift.is_finite()
            && self.kappa_drift >= 0.0)
        {
            return Err(ChainError::Config("κ_F must be > 0 and κ_f ≥ 0"));
        }
        if self.max_degree == Some(0) {
            return Err(ChainError::Config("max_degree must be positive"));
        }
        if let Some(tau) = self.step {
            if !(tau.is_finite() && tau > 0.0) {
                return Err(ChainError::Config("step τ must be positive and finite"));
            }
        }
        if self.control.iter().any(|v| !v.is_finite()) {
            return Err(ChainError::Config("reference control must be finite"));
        }
        Ok(())
    }
}

/// Number of moment equations 1 + d + d(d+1)/2 of the LP kernel.
pub fn moment_equations(dim: usize) -> usize {
    1 + dim + dim * (dim + 1) / 2
}

/// Why a chain operation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChainError {
    /// The state dimension is 0 or above the index's maximum.
    #[error("chain: state dimension {0} unsupported (1..={max})", max = index::MAX_INDEX_DIM)]
    Dimension(usize),
    /// A state of the wrong length or with non-finite coordinates.
    #[error("chain: invalid state ({0})")]
    State(&'static str),
    /// The Gaussian kernel needs F Fᵀ positive definite (thesis §3.6.2).
    #[error("chain: F Fᵀ is singular at a state; the Gaussian kernel needs full-rank diffusion (use the moment-matching kernel)")]
    SingularDiffusion,
    /// A configuration value is out of range.
    #[error("chain config: {0}")]
    Config(&'static str),
    /// A time step that is not positive and finite.
    #[error("chain: time step must be positive and finite, got {0}")]
    Delta(f64),
    /// An imported snapshot is inconsistent.
    #[error(transparent)]
    View(#[from] ViewError),
}
