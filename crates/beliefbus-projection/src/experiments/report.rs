//! The experiment report (the workspace's, `beliefbus_core::report`) and
//! typed `key=value` parameters.

use crate::policy::PolicyError;
use crate::ProjectionError;
use std::str::FromStr;
use thiserror::Error;

/// The workspace's experiment report: a row per method and setting, the
/// paper's rows beside ours.
pub use beliefbus_core::report::{ExperimentReport as Report, Row};

/// Options shared by the experiments (as the root crate's).
#[derive(Clone, Debug)]
pub struct ExperimentArgs {
    /// Repetitions (None: the paper's).
    pub runs: Option<usize>,
    pub seed: u64,
    /// Extra `key=value` parameters.
    pub params: Vec<(String, String)>,
}

impl Default for ExperimentArgs {
    fn default() -> Self {
        Self {
            runs: None,
            seed: 1,
            params: Vec::new(),
        }
    }
}

/// Why an experiment could not run.
#[derive(Debug, Error)]
pub enum ExperimentError {
    #[error("unknown parameter '{name}' (known: {known})")]
    UnknownParam { name: String, known: String },
    #[error("parameter {name}={value}: {detail}")]
    BadParam {
        name: String,
        value: String,
        detail: String,
    },
    #[error(transparent)]
    Projection(#[from] ProjectionError),
    #[error(transparent)]
    Policy(#[from] PolicyError),
}

/// Reject parameters not in `known`.
pub fn check_params(args: &ExperimentArgs, known: &[&str]) -> Result<(), ExperimentError> {
    for (k, _) in &args.params {
        if !known.contains(&k.as_str()) {
            return Err(ExperimentError::UnknownParam {
                name: k.clone(),
                known: known.join(", "),
            });
        }
    }
    Ok(())
}

/// The last value of parameter `key`, parsed, or `default`.
pub fn param<T: FromStr>(args: &ExperimentArgs, key: &str, default: T) -> Result<T, ExperimentError>
where
    T::Err: std::fmt::Display,
{
    match args.params.iter().rev().find(|(k, _)| k == key) {
        Some((_, v)) => v.parse::<T>().map_err(|e| ExperimentError::BadParam {
            name: key.into(),
            value: v.clone(),
            detail: e.to_string(),
        }),
        None => Ok(default),
    }
}

/// A comma-separated list parameter, or `default`.
pub fn list_param(
    args: &ExperimentArgs,
    key: &str,
    default: &[f64],
) -> Result<Vec<f64>, ExperimentError> {
    match args.params.iter().rev().find(|(k, _)| k == key) {
        Some((_, v)) => v
            .split(',')
            .map(|s| {
                s.trim()
                    .parse::<f64>()
                    .map_err(|e| ExperimentError::BadParam {
                        name: key.into(),
                        value: v.clone(),
                        detail: e.to_string(),
                    })
            })
            .collect(),
        None => Ok(default.to_vec()),
    }
}
