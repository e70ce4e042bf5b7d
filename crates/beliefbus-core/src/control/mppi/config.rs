//! MPPI's settings and their validation.

use serde::{Deserialize, Serialize};

/// Settings of MPPI (defaults suit the ship: force limits ±3, 2 s horizon).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MppiConfig {
    /// Number of sampled control sequences K.
    pub samples: usize,
    /// Horizon length T in steps.
    pub horizon_steps: usize,
    /// Rollout step Δ (seconds).
    pub dt: f64,
    /// Temperature λ of the softmax weights (in cost units).
    pub temperature: f64,
    /// σ of the control noise, one per control component.
    pub noise_std: Vec<f64>,
    /// Lower control limits, one per component.
    pub u_min: Vec<f64>,
    /// Upper control limits, one per component.
    pub u_max: Vec<f64>,
    /// Weight r of the quadratic control cost r‖v‖² per unit time.
    pub control_weight: f64,
    /// Savitzky–Golay smoothing of the update (needs horizon_steps ≥ 5).
    pub smoothing: bool,
    /// Seed of the noise stream.
    pub seed: u64,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            samples: 512,
            horizon_steps: 50,
            dt: 0.04,
            temperature: 1.0,
            noise_std: vec![1.5, 1.5],
            u_min: vec![-3.0, -3.0],
            u_max: vec![3.0, 3.0],
            control_weight: 0.05,
            smoothing: true,
            seed: 0,
        }
    }
}

/// An invalid MPPI setting; `key` is the field inside the config section.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {problem}")]
pub struct MppiConfigError {
    pub key: &'static str,
    pub problem: String,
}

pub(super) fn bad(key: &'static str, problem: impl Into<String>) -> MppiConfigError {
    MppiConfigError {
        key,
        problem: problem.into(),
    }
}

impl MppiConfig {
    /// Check every field for a model with `control_dim` controls.
    pub fn validate(&self, control_dim: usize) -> Result<(), MppiConfigError> {
        if self.samples == 0 {
            return Err(bad("samples", "must be at least 1"));
        }
        if self.horizon_steps == 0 {
            return Err(bad("horizon_steps", "must be at least 1"));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(bad("dt", format!("must be positive, got {}", self.dt)));
        }
        if !(self.temperature.is_finite() && self.temperature > 0.0) {
            return Err(bad(
                "temperature",
                format!("must be positive, got {}", self.temperature),
            ));
        }
        if !(self.control_weight.is_finite() && self.control_weight >= 0.0) {
            return Err(bad(
                "control_weight",
                format!("must be non-negative, got {}", self.control_weight),
            ));
        }
        for (key, v) in [
            ("noise_std", &self.noise_std),
            ("u_min", &self.u_min),
            ("u_max", &self.u_max),
        ] {
            if v.len() != control_dim {
                return Err(bad(
                    key,
                    format!(
                        "needs {control_dim} entries (the model's control dimension), got {}",
                        v.len()
                    ),
                ));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(bad(key, "entries must be finite"));
            }
        }
        if self.noise_std.iter().any(|&s| s < 0.0) {
            return Err(bad("noise_std", "entries must be non-negative"));
        }
        if self.u_min.iter().zip(&self.u_max).any(|(lo, hi)| lo > hi) {
            return Err(bad("u_min", "must not exceed u_max"));
        }
        Ok(())
    }
}
