//! The experiment report of DESIGN.md, shared by every experiment of the
//! workspace (the root binary's and the paper crates'): `{"schema_version",
//! "experiment",
//! "params", "results": [{"method", <setting>, <metric>, ...}], "paper":
//! [...]}`, and its text rendering with the paper's rows beside ours.
//! Pure data and formatting: no I/O.

use serde::Serialize;
use serde_json::{Map, Value};

/// One row: a method and its metrics (numbers, or strings such as "diverges").
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
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
    /// Add a numeric metric (non-finite numbers are stored as null).
    pub fn num(mut self, key: &str, v: f64) -> Self {
        let val = serde_json::Number::from_f64(v)
            .map(Value::Number)
            .unwrap_or(Value::Null);
        self.metrics.insert(key.to_string(), val);
        self
    }
    /// Add an integer metric.
    pub fn int(mut self, key: &str, v: u64) -> Self {
        self.metrics.insert(key.to_string(), Value::from(v));
        self
    }
    /// Add a text metric (e.g. "diverges").
    pub fn text(mut self, key: &str, v: &str) -> Self {
        self.metrics.insert(key.to_string(), Value::from(v));
        self
    }
    /// A metric as f64, if numeric.
    pub fn get(&self, key: &str) -> Option<f64> {
        self.metrics.get(key).and_then(Value::as_f64)
    }
}

/// Version of the experiment JSON's layout (`schema_version`): bumped on any
/// incompatible change (a key removed, renamed or changing meaning).
pub const EXPERIMENT_SCHEMA_VERSION: u32 = 1;

/// Result of one experiment.
#[derive(Clone, Debug, Serialize)]
pub struct ExperimentReport {
    /// [`EXPERIMENT_SCHEMA_VERSION`].
    pub schema_version: u32,
    pub experiment: String,
    pub params: Map<String, Value>,
    pub results: Vec<Row>,
    pub paper: Vec<Row>,
    /// Free-text remarks printed under the table (not part of the JSON).
    #[serde(skip)]
    pub notes: Vec<String>,
    /// Columns printed first, in this order (the swept setting, then our
    /// metric beside the paper's); the rest follow in first-seen order.
    #[serde(skip)]
    pub columns: Vec<String>,
}

impl ExperimentReport {
    /// An empty report for `name`.
    pub fn new(name: &str) -> Self {
        Self {
            schema_version: EXPERIMENT_SCHEMA_VERSION,
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

    /// Render the parameters, our rows and the paper's rows as text tables.
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
                    format!("{f:.4e}")
                } else {
                    format!("{f:.5}")
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
            line.push(r.metrics.get(c).map(fmt_value).unwrap_or_else(|| "".into()));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_has_the_design_shape() {
        let mut r = ExperimentReport::new("ship");
        r.param("runs", 10);
        r.results.push(
            Row::new("chain")
                .num("mean_error", 0.005)
                .int("n_states", 100),
        );
        r.paper.push(Row::new("ekf").num("mean_error", 1.36e-2));
        let v: Value = serde_json::to_value(&r).unwrap();
        assert_eq!(v["experiment"], "ship");
        assert_eq!(v["results"][0]["method"], "chain");
        assert_eq!(v["results"][0]["n_states"], 100);
        assert_eq!(v["paper"][0]["mean_error"], 1.36e-2);
        assert!(r.render().contains("chain"));
    }

    #[test]
    fn written_json_parses_back_with_its_schema_version() {
        let mut r = ExperimentReport::new("ship");
        r.param("runs", 3);
        r.results
            .push(Row::new("pf").num("rmse", 0.5).text("note", "ok"));
        r.notes.push("printed only".into());
        let text = serde_json::to_string_pretty(&r).unwrap();
        let v: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["schema_version"], EXPERIMENT_SCHEMA_VERSION);
        assert!(v["schema_version"].is_u64());
        let mut keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        keys.sort_unstable();
        assert_eq!(
            keys,
            ["experiment", "paper", "params", "results", "schema_version"]
        );
        assert_eq!(v["params"]["runs"], 3);
        assert_eq!(v["results"][0]["rmse"], 0.5);
        assert_eq!(v["results"][0]["note"], "ok");
        assert_eq!(v["paper"], serde_json::json!([]));
    }

    #[test]
    fn lead_columns_come_first_and_absent_ones_are_skipped() {
        let mut r = ExperimentReport::new("t");
        r.lead_columns(&["bound", "missing", "sse"]);
        r.results.push(
            Row::new("rbpf")
                .num("sse", 1.0)
                .num("bound", 2.0)
                .num("a", 3.0),
        );
        let text = r.render();
        let header = text.lines().nth(2).unwrap();
        let cols: Vec<&str> = header.split_whitespace().collect();
        assert_eq!(cols, ["method", "bound", "sse", "a"]);
    }
}
