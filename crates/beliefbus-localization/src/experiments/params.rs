//! Typed `key=value` experiment parameters, checked against the
//! experiment's [`ParamDoc`] table (unknown keys refused; in debug builds a
//! default that differs from the table panics, so `--help` cannot drift).

use crate::error::LocalizationError;
use beliefbus_core::experiment_params::{debug_check_default, keys, ParamDoc};
use std::fmt::Display;
use std::str::FromStr;

/// Parameters of one experiment run.
pub struct Params<'a> {
    kv: &'a [(String, String)],
    doc: &'static [ParamDoc],
}

impl<'a> Params<'a> {
    /// Refuse keys the table does not list.
    pub fn new(
        kv: &'a [(String, String)],
        doc: &'static [ParamDoc],
    ) -> Result<Self, LocalizationError> {
        for (k, _) in kv {
            if !doc.iter().any(|d| d.key == k) {
                return Err(LocalizationError::Param {
                    key: k.clone(),
                    msg: format!("unknown (known: {})", keys(doc).join(", ")),
                });
            }
        }
        Ok(Self { kv, doc })
    }

    /// The raw text of `key`, if given (last one wins).
    pub fn raw(&self, key: &str) -> Option<&str> {
        self.kv
            .iter()
            .rev()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The value of `key`, or `default`.
    pub fn get<T: FromStr + Display>(&self, key: &str, default: T) -> Result<T, LocalizationError>
    where
        T::Err: Display,
    {
        debug_check_default(self.doc, key, &default.to_string());
        match self.raw(key) {
            Some(v) => parse(key, v),
            None => Ok(default),
        }
    }

    /// A comma-separated list, or `default`.
    pub fn list<T: FromStr + Display + Clone>(
        &self,
        key: &str,
        default: &[T],
    ) -> Result<Vec<T>, LocalizationError>
    where
        T::Err: Display,
    {
        let shown: Vec<String> = default.iter().map(|v| v.to_string()).collect();
        debug_check_default(self.doc, key, &shown.join(","));
        match self.raw(key) {
            Some(v) => v.split(',').map(|s| parse(key, s.trim())).collect(),
            None => Ok(default.to_vec()),
        }
    }
}

fn parse<T: FromStr>(key: &str, v: &str) -> Result<T, LocalizationError>
where
    T::Err: Display,
{
    v.parse::<T>().map_err(|e| LocalizationError::Param {
        key: key.to_string(),
        msg: format!("'{v}': {e}"),
    })
}

/// Mean and standard error of the mean (NaN where undefined).
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
