//! Rows, reports and typed `key=value` parameters, in the same JSON shape as
//! the root crate's experiment reports (a `Row` is a method plus a flat map
//! of metrics), so registering these experiments there is a field-by-field
//! copy.

use crate::policy::PolicyError;
use crate::ProjectionError;
use serde::Serialize;
use serde_json::{Map, Value};
use std::str::FromStr;
use thiserror::Error;

/// One row: a method and its metrics.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Row {
    pub method: String,
    #[serde(flatten)]
    pub metrics: Map<String, Value>,
}

impl Row {
    pub fn new(method: &str) -> Self {
        Self {
            method: method.to_string(),
            metrics: Map::new(),
        }
    }
    /// A numeric metric (non-finite stored as null).
    pub fn num(mut self, key: &str, v: f64) -> Self {
        let val = serde_json::Number::from_f64(v)
            .map(Value::Number)
            .unwrap_or(Value::Null);
        self.metrics.insert(key.to_string(), val);
        self
    }
    /// The numeric metric `key`, if present.
    pub fn get(&self, key: &str) -> Option<f64> {
        self.metrics.get(key).and_then(Value::as_f64)
    }
}

/// The result of one experiment.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub experiment: String,
    pub params: Map<String, Value>,
    pub results: Vec<Row>,
    pub paper: Vec<Row>,
    /// The side-by-side table and remarks, printed (not part of the JSON).
    #[serde(skip)]
    pub notes: Vec<String>,
}

impl Report {
    pub fn new(name: &str) -> Self {
        Self {
            experiment: name.to_string(),
            params: Map::new(),
            results: vec![],
            paper: vec![],
            notes: vec![],
        }
    }
    pub fn param(&mut self, key: &str, v: impl Into<Value>) {
        self.params.insert(key.to_string(), v.into());
    }
    /// The parameters, then the notes (which hold the side-by-side table).
    pub fn render(&self) -> String {
        let mut out = format!("experiment: {}\nparams:", self.experiment);
        for (k, v) in &self.params {
            out.push_str(&format!(" {k}={v}"));
        }
        out.push('\n');
        for n in &self.notes {
            out.push_str(n);
            out.push('\n');
        }
        out
    }
}

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
