//! Typed errors for filter construction, model parameters and experiment
//! parameters. Nothing on a reachable path panics: bad input comes back here.

use thiserror::Error;

/// Everything this crate can refuse.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ChangepointError {
    /// A probability parameter outside its open interval.
    #[error("{name} = {value} must lie in (0, 1)")]
    Probability { name: &'static str, value: f64 },
    /// A parameter that must be finite and positive.
    #[error("{name} = {value} must be finite and > 0")]
    Positive { name: &'static str, value: f64 },
    /// A parameter that must be ≥ 0 (∞ allowed where documented).
    #[error("{name} = {value} must be ≥ 0 and not NaN")]
    NonNegative { name: &'static str, value: f64 },
    /// A count that must be at least `min`.
    #[error("{name} = {value} must be at least {min}")]
    TooSmall {
        name: &'static str,
        value: usize,
        min: usize,
    },
    /// An observation or input that is NaN or infinite.
    #[error("non-finite {name} = {value}")]
    NonFinite { name: &'static str, value: f64 },
    /// A matrix that should be symmetric positive definite is not.
    #[error("{name} is not symmetric positive definite")]
    NotPositiveDefinite { name: &'static str },
    /// The tilted proposal is only defined for a known ρ.
    #[error("the tilted proposal needs a known ρ (not a Beta prior)")]
    TiltNeedsKnownRho,
    /// Unknown name for a resampling scheme.
    #[error("unknown resampling scheme '{0}' (multinomial, residual, systematic)")]
    UnknownScheme(String),
    /// An experiment parameter that is unknown or does not parse.
    #[error("parameter {key}: {msg}")]
    Param { key: String, msg: String },
    /// All particle weights are zero or NaN (the data are impossible under
    /// the model, e.g. a wildly wrong σ).
    #[error("all particle weights vanished at step {step}")]
    WeightsVanished { step: u64 },
}
