//! The jitter report: the timer floor per core and the pipeline's hops
//! beside it, as ratios.

use super::timer::{CoreTimer, TimerConfig};
use crate::latency::load::LoadReport;
use crate::latency::stats::{ratio, PctBlock};
use crate::rt::LatencyHist;
use serde::{Deserialize, Serialize};

/// One line of the jitter report: a timer (per core, or all cores merged)
/// or a pipeline path, with the same percentile blocks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JitterEntry {
    pub name: String,
    /// The core (timer rows) or null.
    pub core: Option<usize>,
    /// |period − T|.
    pub period_jitter: PctBlock,
    /// Timer: wake-up latency. Pipeline: end-to-end latency.
    pub latency: PctBlock,
    /// Timer: wake-ups after the next deadline. Pipeline: end-to-end
    /// latency above `budget_us`.
    pub deadline_misses: u64,
    /// Periods that passed without a wake-up (timer) or an output
    /// (pipeline).
    pub missed_periods: u64,
    /// The budget misses are counted against, µs (timer: the period;
    /// pipeline: the sum of the ingest, filter and control budgets).
    pub budget_us: Option<f64>,
    /// Period jitter / the timer baseline's, at p50 and p99 (null for the
    /// baseline itself).
    pub ratio_p50: Option<f64>,
    pub ratio_p99: Option<f64>,
    /// Latency / the timer baseline's wake-up latency, at p50 and p99.
    pub latency_ratio_p50: Option<f64>,
    pub latency_ratio_p99: Option<f64>,
}

impl JitterEntry {
    /// An entry without ratios.
    pub fn new(
        name: &str,
        core: Option<usize>,
        period_jitter: &LatencyHist,
        latency: &LatencyHist,
        deadline_misses: u64,
        budget_us: Option<f64>,
    ) -> Self {
        Self {
            name: name.to_string(),
            core,
            period_jitter: PctBlock::of(period_jitter),
            latency: PctBlock::of(latency),
            deadline_misses,
            missed_periods: deadline_misses,
            budget_us,
            ratio_p50: None,
            ratio_p99: None,
            latency_ratio_p50: None,
            latency_ratio_p99: None,
        }
    }

    /// Fill the ratios against `base`.
    pub fn with_ratios(mut self, base: &JitterEntry) -> Self {
        let (j, bj) = (&self.period_jitter, &base.period_jitter);
        let (l, bl) = (&self.latency, &base.latency);
        let both = |a: &PctBlock, b: &PctBlock| a.count > 0 && b.count > 0;
        if both(j, bj) {
            self.ratio_p50 = ratio(j.p50_us, bj.p50_us);
            self.ratio_p99 = ratio(j.p99_us, bj.p99_us);
        }
        if both(l, bl) {
            self.latency_ratio_p50 = ratio(l.p50_us, bl.p50_us);
            self.latency_ratio_p99 = ratio(l.p99_us, bl.p99_us);
        }
        self
    }
}

/// The jitter report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JitterReport {
    pub date: String,
    pub rate_hz: f64,
    pub duration_s: f64,
    /// CPU-stress and memory-bandwidth-stress threads running throughout.
    pub stress_cpu_threads: usize,
    pub stress_mem_threads: usize,
    /// The timer baseline, all cores merged (the reference of the ratios).
    pub baseline: JitterEntry,
    /// The timer baseline per core.
    pub cores: Vec<JitterEntry>,
    /// Pipeline paths, each with its ratios to `baseline`.
    pub paths: Vec<JitterEntry>,
    /// The pipeline run (null with `--timer-only`).
    pub pipeline: Option<PipelineInfo>,
    pub load: LoadReport,
    /// Shared-memory files of the run left after cleanup (should be 0).
    pub shm_left: usize,
    /// Time the machine took from the baseline's cores while it ran
    /// (steal, interrupts; `beliefbus_rt::host`).
    #[serde(default)]
    pub baseline_host: Vec<crate::rt::host::CoreLoss>,
    /// The host stall probe, per core (empty: not run).
    #[serde(default)]
    pub host_stalls: Vec<super::probe::StallRow>,
    /// Whether the probe's stalls sit on a periodic grid, one entry per
    /// period tested (empty: not run, or fewer than two stalls).
    #[serde(default)]
    pub host_stall_grid: Vec<crate::rt::grid::Alignment>,
    pub warnings: Vec<String>,
}

/// What the pipeline run was and what its own report said.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PipelineInfo {
    pub config: String,
    pub sets: Vec<String>,
    pub sensor_rate_hz: f64,
    /// Controls in the measured window.
    pub controls: u64,
    /// Per stage: processed, deadline misses against its compute budget,
    /// compute percentiles (from the run report).
    pub stages: std::collections::BTreeMap<String, crate::latency::pipeline::StageFigures>,
    /// The run report's hops (its whole run after warm-up).
    pub hops: serde_json::Value,
    /// The run report's accuracy (rmse_position, its raw-inversion
    /// reference, ...; after warm-up).
    #[serde(default)]
    pub accuracy: serde_json::Value,
    /// The run report's `host` section: time the machine took from the
    /// stages' cores during the run.
    #[serde(default)]
    pub host: serde_json::Value,
}

/// The baseline entries (merged, per core) of a timer run.
pub fn baseline_entries(cfg: &TimerConfig, cores: &[CoreTimer]) -> (JitterEntry, Vec<JitterEntry>) {
    let period_us = Some(cfg.period_ns() as f64 / 1e3);
    let mut wake = LatencyHist::new();
    let mut jit = LatencyHist::new();
    let mut misses = 0;
    let per_core = cores
        .iter()
        .map(|c| {
            wake.merge(&c.wake);
            jit.merge(&c.period_jitter);
            misses += c.misses;
            JitterEntry::new(
                &format!("timer-core{}", c.core),
                Some(c.core),
                &c.period_jitter,
                &c.wake,
                c.misses,
                period_us,
            )
        })
        .collect();
    (
        JitterEntry::new("timer", None, &jit, &wake, misses, period_us),
        per_core,
    )
}

fn fmt_row(e: &JitterEntry) -> String {
    let r = |x: Option<f64>| x.map(|v| format!("{v:.2}")).unwrap_or_else(|| "-".into());
    format!(
        "{:<18} {:>8} {:>8.1} {:>8.1} {:>8.1} {:>8.1} | {:>8.1} {:>8.1} {:>8.1} {:>8.1} | {:>6} {:>6} {:>6}\n",
        e.name,
        e.period_jitter.count,
        e.period_jitter.p50_us,
        e.period_jitter.p99_us,
        e.period_jitter.p999_us,
        e.period_jitter.max_us,
        e.latency.p50_us,
        e.latency.p99_us,
        e.latency.p999_us,
        e.latency.max_us,
        e.deadline_misses,
        r(e.ratio_p50),
        r(e.ratio_p99),
    )
}

impl JitterReport {
    /// The console table.
    pub fn render(&self) -> String {
        let mut s = format!(
            "jitter at {} Hz, {:.1} s, stress {} cpu + {} mem threads, µs\n",
            self.rate_hz, self.duration_s, self.stress_cpu_threads, self.stress_mem_threads
        );
        s +=
            &format!(
            "{:<18} {:>8} {:>8} {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} {:>8} | {:>6} {:>6} {:>6}\n",
            "", "count", "jit p50", "jit p99", "p99.9", "max", "lat p50", "lat p99", "p99.9", "max",
            "misses", "r p50", "r p99"
        );
        s += &fmt_row(&self.baseline);
        for c in &self.cores {
            s += &fmt_row(c);
        }
        for p in &self.paths {
            s += &fmt_row(p);
        }
        s += "(timer rows: jit = |period − T|, lat = wake-up latency, misses = late by a period; pipeline rows: lat = end-to-end (sensor->ingest for sensor), misses = above the budget, warm-up/after = of those, the ones that started in the stage's first run.warmup_s after its first message and the rest, preempted = of those, the ones whose own CPU time stayed within it, host = of those, the ones never switched out (interrupts or the hypervisor took the time); r = jitter ratio to the timer)\n";
        if !self.baseline_host.is_empty() {
            s += &format!(
                "host time taken during the timer baseline: {}\n",
                crate::rt::host::describe(&self.baseline_host)
            );
        }
        if let Some(p) = &self.pipeline {
            s += &format!(
                "pipeline {} at {} Hz: {} controls measured; stage compute vs budget (µs):\n",
                p.config, p.sensor_rate_hz, p.controls
            );
            let o = |x: Option<f64>| x.map(|v| format!("{v:.1}")).unwrap_or_else(|| "-".into());
            for (name, f) in &p.stages {
                // Why inputs went unprocessed: the reasons with a count.
                let mut why: Vec<String> = f
                    .dropped_by_reason
                    .iter()
                    .filter(|(_, &n)| n > 0)
                    .map(|(r, n)| format!("{r} {n}"))
                    .collect();
                why.push(format!("stale while idle {}", f.dropped_stale_idle));
                s += &format!(
                    "  {:<8} processed {:>8}  dropped {:>5} ({})  compute p50 {:>8} p99 {:>8}  budget {:>8}  misses {:>5} (warm-up {:>3}, after {:>5}; preempted {:>5}, host {:>5})  late {:>5}  lateness p99 {:>8}\n",
                    name,
                    f.processed,
                    f.dropped,
                    why.join(", "),
                    o(f.compute_p50_us),
                    o(f.compute_p99_us),
                    o(f.budget_us),
                    f.deadline_misses,
                    f.deadline_misses_warmup,
                    f.deadline_misses_after_warmup,
                    f.deadline_misses_preempted,
                    f.deadline_misses_host,
                    f.late,
                    o(f.lateness_p99_us)
                );
            }
            // When each miss happened, to line it up with a kernel trace.
            for (name, f) in &p.stages {
                if f.misses_not_listed > 0 {
                    s += &format!(
                        "{} earlier {name} misses not listed (the run report keeps the latest {})\n",
                        f.misses_not_listed,
                        f.misses.len()
                    );
                }
                for m in &f.misses {
                    s += &m.line(name);
                }
            }
        }
        if let Some(p) = &self.pipeline {
            let total: u64 = p.stages.values().map(|f| f.deadline_misses).sum();
            let host: u64 = p.stages.values().map(|f| f.deadline_misses_host).sum();
            let cores: Vec<crate::rt::host::CoreLoss> =
                serde_json::from_value(p.host["cores"].clone()).unwrap_or_default();
            if !cores.is_empty() {
                s += &format!(
                    "host time taken during the pipeline run: {}\n",
                    crate::rt::host::describe(&cores)
                );
            }
            let warm: u64 = p.stages.values().map(|f| f.deadline_misses_warmup).sum();
            s += &format!(
                "deadline misses, all stages: {total} (in the warm-up {warm}, after it {}); taken by the host {host}; the pipeline's own {}\n",
                total - warm,
                total - host
            );
        }
        s += &super::probe::render(&self.host_stalls, self.pipeline.as_ref().map(|p| &p.stages));
        s += &super::probe::render_grid(&self.host_stall_grid);
        if let Some(p) = &self.pipeline {
            let a = |k: &str| {
                p.accuracy[k]
                    .as_f64()
                    .map_or("-".into(), |v| format!("{v:.3}"))
            };
            s += &format!(
                "accuracy after warm-up: rmse_position {} (raw inversion {})\n",
                a("rmse_position"),
                a("rmse_position_raw")
            );
        }
        s += &self.load.line();
        s.push('\n');
        for w in &self.warnings {
            s += &format!("warning: {w}\n");
        }
        s
    }
}
