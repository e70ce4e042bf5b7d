//! The change-point ARX model (13) of Chen, Lai & Wu §3.3 (after Chen & Lai
//! 2007):
//! y_t + a₁y_{t−1} + … + a_k y_{t−k} = b₁u_{t−1} + … + b_h u_{t−h} + ε_t,
//! i.e. y_t = θ_tᵀφ_t + ε_t with φ_t = (−y_{t−1}, …, −y_{t−k}, u_{t−1}, …,
//! u_{t−h})ᵀ (1), ε_t ~ N(0, 1). For t ≥ t₀ + 1, t₀ = max(k, h) + 1, θ_t
//! jumps with probability ρ to a fresh N(μ, V) draw; I_{t₀} = 1.
//!
//! - [`rbpf`]: the fast filter with per-particle Kalman statistics;
//! - [`ls`]: sliding-window and forgetting-factor least squares;
//! - [`control`]: rules (18) and (20);
//! - [`plant`]: a simulator of the model, optionally with stable AR parts.

pub mod bootstrap;
pub mod control;
pub mod linalg;
pub mod ls;
pub mod online;
pub mod plant;
pub mod rbpf;

use crate::error::ChangepointError;
use linalg::{cholesky, Matrix, Vector};

/// The N(μ, V) law of θ after a change-point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThetaPrior<const D: usize> {
    pub mu: Vector<D>,
    pub v: Matrix<D>,
}

impl<const D: usize> ThetaPrior<D> {
    /// Checked: μ finite, V symmetric positive definite.
    pub fn new(mu: Vector<D>, v: Matrix<D>) -> Result<Self, ChangepointError> {
        if mu.iter().any(|x| !x.is_finite()) {
            return Err(ChangepointError::NonFinite {
                name: "prior mean",
                value: f64::NAN,
            });
        }
        for i in 0..D {
            for j in 0..D {
                if (v[i][j] - v[j][i]).abs() > 1e-12 * (1.0 + v[i][j].abs()) {
                    return Err(ChangepointError::NotPositiveDefinite { name: "prior V" });
                }
            }
        }
        cholesky(&v).ok_or(ChangepointError::NotPositiveDefinite { name: "prior V" })?;
        Ok(Self { mu, v })
    }

    /// μ = 0, V = I: the paper's V, and the prior mean we choose (the
    /// paper leaves μ unstated).
    pub fn standard() -> Self {
        Self {
            mu: [0.0; D],
            v: linalg::scaled_identity(1.0),
        }
    }
}

/// The regressor φ_t of (1) kept up to date from past outputs and inputs.
#[derive(Clone, Copy, Debug)]
pub struct Regressor<const D: usize> {
    k: usize,
    phi: Vector<D>,
}

impl<const D: usize> Regressor<D> {
    /// Orders k (outputs) and h = D − k (inputs); lags start at 0.
    pub fn new(k: usize) -> Result<Self, ChangepointError> {
        if k > D || D - k < 1 {
            return Err(ChangepointError::TooSmall {
                name: "input order h = D - k",
                value: D.saturating_sub(k),
                min: 1,
            });
        }
        Ok(Self { k, phi: [0.0; D] })
    }

    /// φ for the next observation.
    pub fn phi(&self) -> &Vector<D> {
        &self.phi
    }

    /// AR order k.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Shift in y_t (after it is observed) and u_t (after it is chosen):
    /// φ_{t+1} = (−y_t, …, −y_{t−k+1}, u_t, …, u_{t−h+1}).
    pub fn push(&mut self, y: f64, u: f64) {
        let k = self.k;
        for i in (1..k).rev() {
            self.phi[i] = self.phi[i - 1];
        }
        if k > 0 {
            self.phi[0] = -y;
        }
        for i in (k + 1..D).rev() {
            self.phi[i] = self.phi[i - 1];
        }
        self.phi[k] = u;
    }
}
