//! A per-step interface for a real-time stage: the filter owns the
//! regressor, so a caller only hands over each output and each input.
//!
//! `observe(y_t)` assimilates y_t with φ_t built from stored lags and
//! returns θ̂_t^(B); `apply(u_t)` records the input chosen afterwards, which
//! enters φ_{t+1}. The first t₀ − 1 outputs only fill the lags (the model
//! starts at t₀ = max(k, h) + 1) and return the prior mean. Nothing
//! allocates after construction.

use super::linalg::Vector;
use super::rbpf::{ArxRbpf, ArxRbpfConfig, Predictive};
use super::{Regressor, ThetaPrior};
use crate::error::ChangepointError;
use crate::rng::SimRng;

/// Change-point ARX tracking from raw (y, u) pairs.
#[derive(Clone, Debug)]
pub struct ArxOnline<const D: usize> {
    filter: ArxRbpf<D>,
    reg: Regressor<D>,
    prior_mu: Vector<D>,
    t: u64,
    t0: u64,
    last_y: f64,
    pending_y: bool,
}

impl<const D: usize> ArxOnline<D> {
    /// AR order k (input order D − k).
    pub fn new(
        k: usize,
        prior: ThetaPrior<D>,
        cfg: ArxRbpfConfig,
        rng: SimRng,
    ) -> Result<Self, ChangepointError> {
        let reg = Regressor::new(k)?;
        Ok(Self {
            filter: ArxRbpf::new(prior, cfg, rng)?,
            reg,
            prior_mu: prior.mu,
            t: 0,
            t0: (k.max(D - k) + 1) as u64,
            last_y: 0.0,
            pending_y: false,
        })
    }

    /// Assimilate y_t; returns θ̂_t^(B).
    pub fn observe(&mut self, y: f64) -> Result<Vector<D>, ChangepointError> {
        if !y.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "y",
                value: y,
            });
        }
        if self.pending_y {
            // No input was applied after the previous output: u = 0.
            self.reg.push(self.last_y, 0.0);
        }
        self.t += 1;
        self.last_y = y;
        self.pending_y = true;
        if self.t < self.t0 {
            return Ok(self.prior_mu);
        }
        self.filter.step(y, self.reg.phi())
    }

    /// Record u_t, the input applied after observing y_t.
    pub fn apply(&mut self, u: f64) -> Result<(), ChangepointError> {
        if !u.is_finite() {
            return Err(ChangepointError::NonFinite {
                name: "u",
                value: u,
            });
        }
        self.reg.push(self.last_y, u);
        self.pending_y = false;
        Ok(())
    }

    /// Moments of the predictive (21) of θ_{t+1}, for rules (18)/(20).
    pub fn predictive(&self) -> Predictive<D> {
        self.filter.predictive()
    }

    /// P(a change-point at some time in [s, t] | data), s in the caller's
    /// time (the first observation is t = 1); for detection delays.
    pub fn prob_change_since(&self, s: u64) -> f64 {
        // The filter counts its own steps from t₀ (its step 1).
        let offset = self.t0 - 1;
        self.filter
            .prob_change_since(s.saturating_sub(offset).max(2))
    }

    /// Observations so far.
    pub fn t(&self) -> u64 {
        self.t
    }

    /// The underlying filter.
    pub fn filter(&self) -> &ArxRbpf<D> {
        &self.filter
    }
}
