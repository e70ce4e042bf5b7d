//! One deadline miss as the run report carries it (JSON `misses`) and the
//! line the report and `beliefbus jitter` print for it.

use serde::{Deserialize, Serialize};

/// One deadline miss of a stage (`beliefbus_rt::miss_log::Miss`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MissReport {
    /// When the message's work started, µs after the run's start
    /// (`run_start_ns`).
    pub t_us: f64,
    /// The same instant on CLOCK_MONOTONIC, ns (an `ftrace` trace with
    /// trace clock `mono`, or `perf record -k mono`, stamps the same clock).
    pub t_ns: u64,
    /// Wall-clock time of the message, µs (above `budget_us`).
    pub wall_us: f64,
    /// The thread's CPU time from the stage's start mark to its record of
    /// the message, µs: it can include publishing the output, after the
    /// end of `wall_us` (null: not measured).
    pub cpu_us: Option<f64>,
    /// The thread's context switches over it (null: not measured).
    pub switches: Option<u64>,
    /// The thread's minor and major page faults over it (same marks as
    /// `switches`; null: not measured). Added with a default: reports
    /// written before them parse.
    #[serde(default)]
    pub minor_faults: Option<u64>,
    #[serde(default)]
    pub major_faults: Option<u64>,
    /// `overrun`, `preempted` or `host` (the rule of `deadline_misses_*`).
    pub kind: String,
}

impl MissReport {
    /// `ingest miss at t=12.345 678 s (mono 8312.104233 s): 115.8 µs wall,
    /// 116.4 µs CPU, 0 switches, 0 faults (overrun)`: `t` after the run's start,
    /// `mono` the CLOCK_MONOTONIC time as an `ftrace` or `perf` trace
    /// prints it (one line, newline included).
    pub fn line(&self, stage: &str) -> String {
        let rel_us = self.t_us.trunc() as i64;
        let sign = if rel_us < 0 { "-" } else { "" };
        let (s, frac) = (rel_us.abs() / 1_000_000, rel_us.abs() % 1_000_000);
        let cpu = self
            .cpu_us
            .map(|c| format!("{c:.1} µs CPU"))
            .unwrap_or("CPU time unknown".into());
        let switches = match self.switches {
            Some(1) => "1 switch".to_string(),
            Some(n) => format!("{n} switches"),
            None => "switches unknown".to_string(),
        };
        let faults = match (self.minor_faults, self.major_faults) {
            (Some(1), Some(0)) => "1 fault".to_string(),
            (Some(minor), Some(0)) => format!("{minor} faults"),
            (Some(minor), Some(major)) => format!("{} faults ({major} major)", minor + major),
            _ => "faults unknown".to_string(),
        };
        format!(
            "{stage} miss at t={sign}{s}.{:03} {:03} s (mono {}.{:06} s): {:.1} µs wall, {cpu}, {switches}, {faults} ({})\n",
            frac / 1_000,
            frac % 1_000,
            self.t_ns / 1_000_000_000,
            self.t_ns % 1_000_000_000 / 1_000,
            self.wall_us,
            self.kind
        )
    }
}
