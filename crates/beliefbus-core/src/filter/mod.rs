//! Bayes filters behind one trait. A filter holds a belief over the state of
//! an [`crate::model::SdeModel`] at a time t; `predict` propagates it under a
//! held control to a later time, `update` conditions it on a measurement
//! taken at its current time (Bayes' rule, thesis eq. 3.6):
//!
//! ```text
//! p(x_k | y_{1:k}) ∝ p(y_k | x_k) ∫ p(x_k | x_{k−1}, u) p(x_{k−1} | y_{1:k−1}) dx_{k−1}
//! ```
//!
//! Backends: bootstrap particle filter, EKF, UKF, Kalman (exact reference
//! on linear models), and the Markov-chain filter of thesis ch. 3.

pub mod build;
#[cfg(test)]
mod chain_collapse_tests;
pub mod chain_filter;
pub mod chain_spec;
pub mod control_transport;
pub mod decoder;
pub mod ekf;
pub mod gauss;
mod gauss_state;
pub mod kalman;
pub mod layered_decoder;
pub mod live_chain;
pub mod pf;
pub mod regularise;
pub mod resample;
pub mod rts;
pub mod smoother;
#[cfg(test)]
mod step_check_tests;
pub mod ukf;

use crate::belief::Gaussian;
use crate::model::{Dims, Measurement};

/// Why a filter refused a step. A refused step leaves the belief unchanged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// `predict` to a time before the filter's current time.
    #[error("time goes backwards: filter at {now} s, asked for {asked} s")]
    TimeBackwards { now: f64, asked: f64 },
    /// A vector of the wrong length.
    #[error("{what} has length {got}, expected {expected}")]
    Dimension {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    /// A NaN or infinite value in the input.
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    /// The measurement has zero likelihood under every hypothesis (all
    /// weights vanished); the belief is kept as it was before the update.
    #[error("measurement is impossible under the current belief (all weights vanished)")]
    Degenerate,
    /// The belief became numerically invalid (e.g. non-positive-definite
    /// covariance); the filter kept its previous belief.
    #[error("numerical failure: {0}")]
    Numerical(&'static str),
}

/// Diagnostics of one update.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateInfo {
    /// Log marginal likelihood log p(y_k | y_{1:k−1}) (approximate).
    pub log_evidence: f64,
    /// Effective sample size after the update (support size for grid /
    /// chain filters, 1 for Gaussian filters).
    pub ess: f64,
    /// Whether the update triggered a resampling step.
    pub resampled: bool,
}

/// A recursive Bayes filter.
pub trait BayesFilter: Send {
    /// Backend name (`pf`, `ekf`, `ukf`, `kalman`, `chain`).
    fn name(&self) -> &'static str;
    /// Dimensions of the model it filters.
    fn dims(&self) -> Dims;
    /// Time of the current belief (seconds).
    fn time(&self) -> f64;
    /// Restart from the prior N(mean, cov) at time `t`.
    fn reset(&mut self, t: f64, prior: &Gaussian);
    /// Propagate the belief to time `t ≥ self.time()` with control `u` held
    /// constant (`u` has the model's control dimension).
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError>;
    /// Condition on a measurement taken at the current time.
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError>;
    /// Mean and covariance of the current belief.
    fn belief(&self) -> Gaussian;
    /// Steps that collapsed since construction (see
    /// [`regularise`](self::regularise): an update that kept less than a
    /// fraction of its effective support, or whose weights all vanished);
    /// None for filters without weights (the Gaussian filters).
    fn ess_collapses(&self) -> Option<u64> {
        None
    }
}

/// Check the inputs common to every backend's `predict`.
pub fn check_predict(now: f64, t: f64, u: &[f64], dims: Dims) -> Result<(), FilterError> {
    if !t.is_finite() {
        return Err(FilterError::NonFinite("time"));
    }
    if t < now {
        return Err(FilterError::TimeBackwards { now, asked: t });
    }
    if u.len() != dims.control {
        return Err(FilterError::Dimension {
            what: "control",
            got: u.len(),
            expected: dims.control,
        });
    }
    if u.iter().any(|v| !v.is_finite()) {
        return Err(FilterError::NonFinite("control"));
    }
    Ok(())
}

/// Check the inputs common to every backend's `update`.
pub fn check_measurement(meas: &Measurement, dims: Dims) -> Result<(), FilterError> {
    if meas.y.len() != dims.obs {
        return Err(FilterError::Dimension {
            what: "observation",
            got: meas.y.len(),
            expected: dims.obs,
        });
    }
    if meas.mask.iter().any(|i| i >= dims.obs) {
        return Err(FilterError::Dimension {
            what: "observation mask",
            got: meas.mask.count(),
            expected: dims.obs,
        });
    }
    if meas.mask.iter().any(|i| !meas.y[i].is_finite()) {
        return Err(FilterError::NonFinite("observation"));
    }
    if let Some(s) = meas.std {
        if s.len() != dims.obs {
            return Err(FilterError::Dimension {
                what: "observation std",
                got: s.len(),
                expected: dims.obs,
            });
        }
        if meas.mask.iter().any(|i| !(s[i].is_finite() && s[i] > 0.0)) {
            return Err(FilterError::NonFinite("observation std"));
        }
    }
    Ok(())
}
