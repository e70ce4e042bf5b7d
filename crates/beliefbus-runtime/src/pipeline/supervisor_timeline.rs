//! The run's timeline (`beliefbus run --timeline FILE`, the soak of
//! `tools/soak`): every `--timeline-period` seconds one JSON line with the
//! resident memory of every stage process and of the launcher
//! (`/proc/<pid>/status` VmRSS), the number of shared-memory files of the
//! run, the restarts so far, and the sensor → output (control; belief in
//! estimation-only runs) latency percentiles over that period.
//!
//! The summary compares the first sample with the last:
//! `rss_growth_pct = 100 · (rss_last − rss_first) / rss_first` on the total
//! RSS, and the p99 drift `p99_last / p99_first` together with the median and
//! the largest per-period p99 (a drift shows as a trend, a spike as a max).

use crate::ipc::{Percentiles, StageKind};
use serde::Serialize;
use serde_json::{json, Value};
use std::io::Write;
use std::path::Path;

/// Resident set size of process `pid` in KiB (None if it is gone).
pub fn rss_kb(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
}

/// One timeline sample.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Sample {
    /// Seconds since the plant started.
    pub t_s: f64,
    /// (stage, KiB) of each running stage.
    pub rss_kb: Vec<(String, u64)>,
    pub launcher_rss_kb: u64,
    /// Sum over the stages and the launcher.
    pub rss_total_kb: u64,
    pub shm_files: usize,
    pub restarts: u64,
    /// Outputs in the period and their sensor → output latency (µs).
    pub outputs: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
}

impl Sample {
    /// Build a sample from its parts.
    pub fn new(
        t_s: f64,
        stages: &[(StageKind, u32)],
        shm_files: usize,
        restarts: u64,
        window: &Percentiles,
    ) -> Self {
        let rss: Vec<(String, u64)> = stages
            .iter()
            .filter_map(|(k, pid)| rss_kb(*pid).map(|r| (k.name().to_string(), r)))
            .collect();
        let me = rss_kb(std::process::id()).unwrap_or(0);
        let us = |ns: u64| ns as f64 / 1e3;
        Self {
            t_s,
            rss_total_kb: me + rss.iter().map(|(_, r)| r).sum::<u64>(),
            rss_kb: rss,
            launcher_rss_kb: me,
            shm_files,
            restarts,
            outputs: window.count,
            p50_us: us(window.p50_ns),
            p99_us: us(window.p99_ns),
            max_us: us(window.max_ns),
        }
    }

    /// The JSON line.
    pub fn to_json(&self) -> Value {
        let rss: serde_json::Map<String, Value> = self
            .rss_kb
            .iter()
            .map(|(k, v)| (k.clone(), json!(v)))
            .collect();
        json!({
            "t_s": self.t_s,
            "rss_kb": rss,
            "launcher_rss_kb": self.launcher_rss_kb,
            "rss_total_kb": self.rss_total_kb,
            "shm_files": self.shm_files,
            "restarts": self.restarts,
            "outputs": self.outputs,
            "p50_us": self.p50_us,
            "p99_us": self.p99_us,
            "max_us": self.max_us,
        })
    }
}

/// The samples so far, optionally mirrored to a JSON-lines file.
#[derive(Debug, Default)]
pub struct Timeline {
    samples: Vec<Sample>,
    file: Option<std::fs::File>,
}

impl Timeline {
    /// A timeline written to `path` (if given) as it grows.
    pub fn create(path: Option<&Path>) -> std::io::Result<Self> {
        Ok(Self {
            samples: Vec::new(),
            file: path.map(crate::rt::files::create_no_follow).transpose()?,
        })
    }

    /// Append a sample (and write its line).
    pub fn push(&mut self, s: Sample) {
        if let Some(f) = self.file.as_mut() {
            let _ = writeln!(f, "{}", s.to_json());
            let _ = f.flush();
        }
        self.samples.push(s);
    }

    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    /// The summary of the report's `timeline` section (null without samples).
    pub fn summary(&self) -> Value {
        let (Some(first), Some(last)) = (self.samples.first(), self.samples.last()) else {
            return Value::Null;
        };
        let growth = if first.rss_total_kb > 0 {
            100.0 * (last.rss_total_kb as f64 - first.rss_total_kb as f64)
                / first.rss_total_kb as f64
        } else {
            0.0
        };
        let mut p99: Vec<f64> = self
            .samples
            .iter()
            .filter(|s| s.outputs > 0)
            .map(|s| s.p99_us)
            .collect();
        let first_p99 = self
            .samples
            .iter()
            .find(|s| s.outputs > 0)
            .map(|s| s.p99_us);
        let last_p99 = self
            .samples
            .iter()
            .rev()
            .find(|s| s.outputs > 0)
            .map(|s| s.p99_us);
        p99.sort_by(f64::total_cmp);
        let median = (!p99.is_empty()).then(|| p99[p99.len() / 2]);
        json!({
            "samples": self.samples.len(),
            "rss_first_kb": first.rss_total_kb,
            "rss_last_kb": last.rss_total_kb,
            "rss_max_kb": self.samples.iter().map(|s| s.rss_total_kb).max(),
            "rss_growth_pct": growth,
            "shm_files_first": first.shm_files,
            "shm_files_last": last.shm_files,
            "p99_first_us": first_p99,
            "p99_last_us": last_p99,
            "p99_median_us": median,
            "p99_max_us": p99.last(),
            "p99_drift_ratio": match (first_p99, last_p99) {
                (Some(a), Some(b)) if a > 0.0 => json!(b / a),
                _ => Value::Null,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t: f64, rss: u64, p99: f64, outputs: u64) -> Sample {
        Sample {
            t_s: t,
            rss_kb: vec![("filter".into(), rss)],
            launcher_rss_kb: 0,
            rss_total_kb: rss,
            shm_files: 7,
            restarts: 0,
            outputs,
            p50_us: p99 / 2.0,
            p99_us: p99,
            max_us: p99 * 2.0,
        }
    }

    #[test]
    fn summary_reports_growth_and_drift() {
        let mut t = Timeline::default();
        assert!(t.summary().is_null());
        t.push(sample(60.0, 1000, 100.0, 10));
        t.push(sample(120.0, 1005, 400.0, 10));
        t.push(sample(180.0, 1010, 0.0, 0)); // no outputs: not a latency sample
        t.push(sample(240.0, 1020, 200.0, 10));
        let s = t.summary();
        assert_eq!(s["samples"], 4);
        assert!((s["rss_growth_pct"].as_f64().unwrap() - 2.0).abs() < 1e-12);
        assert_eq!(s["p99_first_us"], 100.0);
        assert_eq!(s["p99_last_us"], 200.0);
        assert_eq!(s["p99_max_us"], 400.0);
        assert_eq!(s["p99_median_us"], 200.0);
        assert_eq!(s["p99_drift_ratio"], 2.0);
    }

    #[test]
    fn rss_of_this_process_is_read_from_proc() {
        let r = rss_kb(std::process::id()).unwrap();
        assert!(r > 100, "{r}");
        assert_eq!(rss_kb(u32::MAX - 1), None);
    }
}
