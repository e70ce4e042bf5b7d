//! The normal mean-shift model of Chen, Lai & Wu §3.1–3.2:
//! y_t ~ N(μ_t, 1) independently; with probability 1 − ρ, μ_t = μ_{t−1},
//! with probability ρ, μ_t is a fresh N(0, σ²) draw; μ₀ ~ N(0, σ²).
//!
//! Conditioning on the change indicators I_t = 1{μ_t ≠ μ_{t−1}} integrates
//! μ out: given the last change-point C_t, μ_t | Y ~ N(S/(n + σ⁻²),
//! 1/(n + σ⁻²)) with n = t − C_t + 1 observations and S their sum (eq. 9).
//! Every filter here carries that segment statistic (n, S).

pub mod bootstrap;
pub mod exact;
pub mod rbpf;

use crate::error::ChangepointError;
use rand::{Rng, RngExt};
use rand_distr::{Distribution, StandardNormal};

/// Model parameters. The observation variance is 1 as in the paper.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MeanShiftModel {
    /// Prior standard deviation σ of a new level.
    pub sigma: f64,
    /// Change probability ρ per step.
    pub rho: f64,
}

impl MeanShiftModel {
    /// Checked constructor.
    pub fn new(sigma: f64, rho: f64) -> Result<Self, ChangepointError> {
        if !(sigma > 0.0 && sigma.is_finite()) {
            return Err(ChangepointError::Positive {
                name: "sigma",
                value: sigma,
            });
        }
        check_probability("rho", rho)?;
        Ok(Self { sigma, rho })
    }

    /// Simulate n steps into `mu` (true levels) and `y` (observations),
    /// both cleared first.
    pub fn simulate<R: Rng + ?Sized>(
        &self,
        n: usize,
        rng: &mut R,
        mu: &mut Vec<f64>,
        y: &mut Vec<f64>,
    ) {
        mu.clear();
        y.clear();
        let normal = |r: &mut R| -> f64 { StandardNormal.sample(r) };
        let mut level = self.sigma * normal(rng);
        for _ in 0..n {
            if rng.random::<f64>() < self.rho {
                level = self.sigma * normal(rng);
            }
            mu.push(level);
            y.push(level + normal(rng));
        }
    }
}

/// Refuse a probability outside (0, 1).
pub(crate) fn check_probability(name: &'static str, value: f64) -> Result<(), ChangepointError> {
    if value > 0.0 && value < 1.0 {
        Ok(())
    } else {
        Err(ChangepointError::Probability { name, value })
    }
}

/// Posterior mean of μ given a segment of `n` observations summing to `s`
/// under the N(0, σ²) prior (eq. 9's inner expectation).
#[inline]
pub fn segment_mean(n: u32, s: f64, inv_sigma2: f64) -> f64 {
    s / (n as f64 + inv_sigma2)
}
