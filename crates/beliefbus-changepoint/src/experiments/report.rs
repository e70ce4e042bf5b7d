//! The experiment report (the workspace's, `beliefbus_core::report`: rows of
//! `{"method", <swept setting>, <metric>, <metric>_se, "time_s"}` with the
//! paper's beside ours) and the typed `key=value` parameters of these
//! experiments.

use crate::error::ChangepointError;
use beliefbus_core::experiment_params::{p, ParamDoc};
use serde_json::Value;
use std::str::FromStr;

/// The workspace's experiment report: a row per method and setting, the
/// paper's rows beside ours, lead columns for the swept setting.
pub use beliefbus_core::report::{ExperimentReport as Report, Row};

/// Experiment parameters `key=value`, validated against a known list.
pub struct Params<'a> {
    kv: &'a [(String, String)],
}

impl<'a> Params<'a> {
    /// Refuse unknown keys.
    pub fn new(kv: &'a [(String, String)], known: &[&str]) -> Result<Self, ChangepointError> {
        for (k, _) in kv {
            if !known.contains(&k.as_str()) {
                return Err(ChangepointError::Param {
                    key: k.clone(),
                    msg: format!("unknown (known: {})", known.join(", ")),
                });
            }
        }
        Ok(Self { kv })
    }

    fn raw(&self, key: &str) -> Option<&str> {
        self.kv
            .iter()
            .rev()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The value of `key`, or `default`.
    pub fn get<T: FromStr>(&self, key: &str, default: T) -> Result<T, ChangepointError>
    where
        T::Err: std::fmt::Display,
    {
        match self.raw(key) {
            Some(v) => parse(key, v),
            None => Ok(default),
        }
    }

    /// A comma-separated list, or `default`.
    pub fn list<T: FromStr + Clone>(
        &self,
        key: &str,
        default: &[T],
    ) -> Result<Vec<T>, ChangepointError>
    where
        T::Err: std::fmt::Display,
    {
        match self.raw(key) {
            Some(v) => v.split(',').map(|s| parse(key, s.trim())).collect(),
            None => Ok(default.to_vec()),
        }
    }
}

fn parse<T: FromStr>(key: &str, v: &str) -> Result<T, ChangepointError>
where
    T::Err: std::fmt::Display,
{
    // "inf" parses as f64::INFINITY already; accept "∞" too.
    let v = if v == "∞" { "inf" } else { v };
    v.parse::<T>().map_err(|e| ChangepointError::Param {
        key: key.to_string(),
        msg: format!("'{v}': {e}"),
    })
}

/// Refuse zero repetitions (every statistic would be empty).
pub fn check_runs(runs: usize) -> Result<usize, ChangepointError> {
    if runs == 0 {
        return Err(ChangepointError::TooSmall {
            name: "runs",
            value: 0,
            min: 1,
        });
    }
    Ok(runs)
}

/// Mean and standard error of the mean.
pub fn mean_se(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    if x.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = x.iter().sum::<f64>() / n;
    if x.len() < 2 {
        return (m, f64::NAN);
    }
    let v = x.iter().map(|a| (a - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (v / n).sqrt())
}

/// A bound or setting for a table cell: "inf" for ∞.
pub fn setting(v: f64) -> Value {
    if v.is_infinite() {
        Value::from("inf")
    } else {
        serde_json::Number::from_f64(v)
            .map(Value::Number)
            .unwrap_or(Value::Null)
    }
}

/// The `--param` rows every experiment of this crate shares.
pub const N_SEQ: ParamDoc = p("n", "10000", "observations per sequence");
pub const N_ARX: ParamDoc = p("n", "3000", "steps per sequence");
pub const PARTICLES: ParamDoc = p("particles", "50", "particles M");
pub const SIGMA: ParamDoc = p(
    "sigma",
    "1",
    "jump size standard deviation sigma of the mean-shift model",
);
pub const RHO: ParamDoc = p("rho", "0.001", "change-point probability per step");
pub const BOUND: ParamDoc = p("bound", "1", "cv2 rejuvenation bound");
pub const THREADS: ParamDoc = p(
    "threads",
    "= cores, at most 2",
    "worker threads over sequences",
);
