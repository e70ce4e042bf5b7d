//! Errors of building a filter backend from its config and prior.

use super::FilterError;

/// A config value out of range; `key` is the field name inside the
/// backend's config section (the pipeline prefixes its section path).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {problem}")]
pub struct ConfigError {
    pub key: &'static str,
    pub problem: String,
}

impl ConfigError {
    pub(crate) fn new(key: &'static str, problem: impl Into<String>) -> Self {
        Self {
            key,
            problem: problem.into(),
        }
    }
}

/// Why a filter could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BuildError {
    /// The config is invalid.
    #[error("filter config: {0}")]
    Config(#[from] ConfigError),
    /// The model, prior or start time is unusable.
    #[error("filter start: {0}")]
    Start(#[from] FilterError),
}

/// `v` must be finite and > 0.
pub(crate) fn positive(key: &'static str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(ConfigError::new(
            key,
            format!("must be positive and finite, got {v}"),
        ))
    }
}

/// Check the model's dimensions against the crate's compile-time maxima.
pub(crate) fn check_dims(dims: crate::model::Dims) -> Result<(), FilterError> {
    use crate::{MAX_CONTROL, MAX_NOISE, MAX_OBS, MAX_STATE};
    for (what, got, max) in [
        ("model state", dims.state, MAX_STATE),
        ("model noise", dims.noise, MAX_NOISE),
        ("model observation", dims.obs, MAX_OBS),
        ("model control", dims.control, MAX_CONTROL),
    ] {
        if got > max || (what == "model state" && got == 0) {
            return Err(FilterError::Dimension {
                what,
                got,
                expected: max,
            });
        }
    }
    Ok(())
}
