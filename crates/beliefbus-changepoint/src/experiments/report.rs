//! The project's experiment JSON shape, `{"experiment", "params",
//! "results": [{"method", <swept setting>, <metric>, <metric>_se, "time_s"}],
//! "paper": [...]}`, and a text rendering that puts the paper's figure
//! beside ours. Mirrors the `beliefbus` binary's report so registering these
//! experiments there is a field-by-field copy.

use crate::error::ChangepointError;
use serde::Serialize;
use serde_json::{Map, Value};
use std::str::FromStr;

/// One row: a method and its metrics.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Row {
    pub method: String,
    #[serde(flatten)]
    pub metrics: Map<String, Value>,
}

impl Row {
    /// A row for `method` with no metrics yet.
    pub fn new(method: &str) -> Self {
        Self {
            method: method.to_string(),
            metrics: Map::new(),
        }
    }
    /// Add a number (non-finite numbers become null; ∞ settings use text).
    pub fn num(mut self, key: &str, v: f64) -> Self {
        let val = serde_json::Number::from_f64(v)
            .map(Value::Number)
            .unwrap_or(Value::Null);
        self.metrics.insert(key.to_string(), val);
        self
    }
    /// Add an integer.
    pub fn int(mut self, key: &str, v: u64) -> Self {
        self.metrics.insert(key.to_string(), Value::from(v));
        self
    }
    /// Add a text value.
    pub fn text(mut self, key: &str, v: &str) -> Self {
        self.metrics.insert(key.to_string(), Value::from(v));
        self
    }
    /// A metric as f64, if numeric.
    pub fn get(&self, key: &str) -> Option<f64> {
        self.metrics.get(key).and_then(Value::as_f64)
    }
}

/// One experiment's output.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub experiment: String,
    pub params: Map<String, Value>,
    pub results: Vec<Row>,
    pub paper: Vec<Row>,
    /// Remarks printed under the tables (not part of the JSON).
    #[serde(skip)]
    pub notes: Vec<String>,
    /// Columns printed first, in this order (the swept setting, then our
    /// metric beside the paper's); the rest follow alphabetically.
    #[serde(skip)]
    pub columns: Vec<String>,
}

impl Report {
    /// An empty report.
    pub fn new(name: &str) -> Self {
        Self {
            experiment: name.to_string(),
            params: Map::new(),
            results: vec![],
            paper: vec![],
            notes: vec![],
            columns: vec![],
        }
    }
    /// Print these columns first, in this order.
    pub fn lead_columns(&mut self, cols: &[&str]) {
        self.columns = cols.iter().map(|c| c.to_string()).collect();
    }
    /// Record a parameter.
    pub fn param(&mut self, key: &str, v: impl Into<Value>) {
        self.params.insert(key.to_string(), v.into());
    }
    /// Parameters, our rows (with the paper's columns beside them where the
    /// experiment adds `paper_*` keys) and the paper's rows, as text.
    pub fn render(&self) -> String {
        let mut out = format!("experiment: {}\n", self.experiment);
        if !self.params.is_empty() {
            out.push_str("params:");
            for (k, v) in &self.params {
                out.push_str(&format!(" {k}={v}"));
            }
            out.push('\n');
        }
        out.push_str(&table("ours", &self.results, &self.columns));
        if !self.paper.is_empty() {
            out.push_str(&table("paper", &self.paper, &self.columns));
        }
        for n in &self.notes {
            out.push_str(&format!("note: {n}\n"));
        }
        out
    }
}

fn fmt_value(v: &Value) -> String {
    match v {
        Value::Number(n) => match n.as_f64() {
            Some(f) if n.is_f64() => {
                let a = f.abs();
                if a != 0.0 && !(1e-3..1e5).contains(&a) {
                    format!("{f:.3e}")
                } else {
                    format!("{f:.4}")
                }
            }
            _ => n.to_string(),
        },
        Value::Null => "-".into(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

fn table(title: &str, rows: &[Row], lead: &[String]) -> String {
    let mut cols: Vec<String> = lead
        .iter()
        .filter(|c| rows.iter().any(|r| r.metrics.contains_key(c.as_str())))
        .cloned()
        .collect();
    for r in rows {
        for k in r.metrics.keys() {
            if !cols.contains(k) {
                cols.push(k.clone());
            }
        }
    }
    let mut cells: Vec<Vec<String>> = vec![std::iter::once("method".to_string())
        .chain(cols.iter().cloned())
        .collect()];
    for r in rows {
        let mut line = vec![r.method.clone()];
        for c in &cols {
            line.push(r.metrics.get(c).map(fmt_value).unwrap_or_default());
        }
        cells.push(line);
    }
    let widths: Vec<usize> = (0..cells[0].len())
        .map(|j| cells.iter().map(|l| l[j].len()).max().unwrap_or(0))
        .collect();
    let mut out = format!("-- {title} --\n");
    for l in &cells {
        let s: Vec<String> = l
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{c:>w$}"))
            .collect();
        out.push_str(&s.join("  "));
        out.push('\n');
    }
    out
}

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
