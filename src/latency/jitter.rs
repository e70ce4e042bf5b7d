//! Jitter: the machine's timer floor and the pipeline against it.
//!
//! **Timer baseline** (after cyclictest): one thread per core, pinned, at
//! SCHED_FIFO when permitted, sleeps to absolute deadlines
//! `t_k = t_0 + k·T` with `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`
//! and reads the clock on waking:
//! - wake-up latency `L_k = t_wake,k − t_k` (cyclictest's figure);
//! - period jitter `J_k = |(t_wake,k − t_wake,k−1) − T|`, the same figure
//!   the pipeline's control output is judged by;
//! - a deadline miss when a wake-up comes after the next deadline
//!   (`L_k ≥ T`): those periods are skipped, as cyclictest does, and each
//!   skipped period counts as one miss.
//!
//! All cores run at once (like `cyclictest -a -t`), so the baseline sees the
//! same machine the pipeline does.

use super::hdr::HdrLog;
use super::load::LoadReport;
use super::stats::{ratio, PctBlock};
use super::LatencyError;
use crate::rt::clock::{now_ns, sleep_until_ns};
use crate::rt::{sched, LatencyHist};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, SystemTime};

/// Settings of the timer baseline.
#[derive(Clone, Debug)]
pub struct TimerConfig {
    /// Wake-ups per second.
    pub rate_hz: f64,
    pub duration: Duration,
    /// Cores to measure (one thread each).
    pub cores: Vec<usize>,
    /// SCHED_FIFO priority (None: SCHED_OTHER).
    pub fifo: Option<u8>,
    /// Keep one HdrHistogram interval per second.
    pub hdr_logs: bool,
}

impl TimerConfig {
    /// Check ranges before starting.
    pub fn validate(&self) -> Result<(), LatencyError> {
        if !(self.rate_hz.is_finite() && (1.0..=100_000.0).contains(&self.rate_hz)) {
            return Err(LatencyError::BadArg(format!(
                "--rate must be 1..=100000 Hz, got {}",
                self.rate_hz
            )));
        }
        if self.duration < Duration::from_millis(100) || self.duration > Duration::from_secs(86_400)
        {
            return Err(LatencyError::BadArg(
                "--duration must be between 0.1 and 86400 seconds".into(),
            ));
        }
        if self.cores.is_empty() {
            return Err(LatencyError::BadArg("no core to measure".into()));
        }
        let n = sched::available_cores();
        if let Some(c) = self.cores.iter().find(|&&c| c >= n) {
            return Err(LatencyError::BadArg(format!(
                "core {c} is not available (0..{})",
                n - 1
            )));
        }
        if let Some(p) = self.fifo {
            if !(1..=99).contains(&p) {
                return Err(LatencyError::BadArg(format!(
                    "--fifo must be 1..=99, got {p}"
                )));
            }
        }
        Ok(())
    }

    /// The period in ns.
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }
}

/// One core's timer results.
#[derive(Debug)]
pub struct CoreTimer {
    pub core: usize,
    /// Ran under SCHED_FIFO.
    pub fifo: bool,
    pub wake: LatencyHist,
    pub period_jitter: LatencyHist,
    pub misses: u64,
    pub wakeups: u64,
    pub warnings: Vec<String>,
    pub wake_log: Option<HdrLog>,
    pub jitter_log: Option<HdrLog>,
}

/// One filled pair of interval histograms (wake-up latency, period
/// jitter) on its way to the log writer, with its start and length.
type Interval = (Duration, Duration, [LatencyHist; 2]);

/// The timer thread's end of the log writer: full intervals out, empty
/// histograms back (a small pool, so the timer thread never allocates,
/// serialises or blocks — a late writer only makes an interval longer).
struct IntervalTx {
    full: crossbeam::channel::Sender<Interval>,
    empty: crossbeam::channel::Receiver<[LatencyHist; 2]>,
}

/// Histogram pairs in flight per core.
const POOL: usize = 4;
/// Length of a log interval.
const IV_NS: u64 = 1_000_000_000;

/// Write intervals into the two logs until the timer thread hangs up.
fn log_writer(
    mut logs: [HdrLog; 2],
    full: crossbeam::channel::Receiver<Interval>,
    empty: crossbeam::channel::Sender<[LatencyHist; 2]>,
) -> Result<[HdrLog; 2], LatencyError> {
    let mut err = None;
    for (a, d, mut pair) in full {
        for (log, h) in logs.iter_mut().zip(pair.iter_mut()) {
            if let Err(e) = log.add(h, a, d) {
                err.get_or_insert(e);
            }
            h.reset();
        }
        let _ = empty.send(pair);
    }
    match err {
        Some(e) => Err(LatencyError::Output {
            path: "hdr log".into(),
            reason: e.to_string(),
        }),
        None => Ok(logs),
    }
}

fn timer_thread(
    cfg: &TimerConfig,
    core: usize,
    start_ns: u64,
    stop: &AtomicBool,
    logs: Option<IntervalTx>,
) -> CoreTimer {
    let mut warnings = Vec::new();
    if let Err(e) = sched::pin_to_core(core) {
        warnings.push(format!("timer core {core}: cannot pin ({e})"));
    }
    let mut fifo = false;
    if let Some(p) = cfg.fifo {
        match sched::set_fifo(p) {
            Ok(()) => fifo = true,
            Err(e) => warnings.push(format!(
                "timer core {core}: SCHED_FIFO {p} not permitted ({e}); SCHED_OTHER"
            )),
        }
    }
    let mut out = CoreTimer {
        core,
        fifo,
        wake: LatencyHist::new(),
        period_jitter: LatencyHist::new(),
        misses: 0,
        wakeups: 0,
        warnings,
        wake_log: None,
        jitter_log: None,
    };
    let mut iv = [LatencyHist::new(), LatencyHist::new()];
    let t_ns = cfg.period_ns();
    let end_ns = start_ns + cfg.duration.as_nanos() as u64;
    let mut next = start_ns + t_ns;
    let mut prev_wake: Option<u64> = None;
    let mut iv_start = start_ns;
    // Hand the interval's pair to the writer if a fresh pair is at hand;
    // otherwise keep recording into this one (the interval grows).
    let flush = |iv: &mut [LatencyHist; 2], from: u64, to: u64| -> bool {
        let Some(l) = &logs else {
            return false;
        };
        let Ok(fresh) = l.empty.try_recv() else {
            return false;
        };
        let pair = std::mem::replace(iv, fresh);
        let at = Duration::from_nanos(from - start_ns);
        let len = Duration::from_nanos(to - from);
        // The channel holds every pair there is, so this never fails.
        let _ = l.full.try_send((at, len, pair));
        true
    };
    while next <= end_ns && !stop.load(Ordering::Relaxed) {
        sleep_until_ns(next);
        let t = now_ns();
        if t < next {
            continue; // a signal woke us early: sleep again
        }
        let lat = t - next;
        out.wake.record(lat);
        iv[0].record(lat);
        out.wakeups += 1;
        if let Some(pw) = prev_wake {
            let j = (t - pw).abs_diff(t_ns);
            out.period_jitter.record(j);
            iv[1].record(j);
        }
        prev_wake = Some(t);
        next += t_ns;
        while next <= t {
            // A deadline passed while we were late: missed (if it lies
            // within the run).
            out.misses += (next <= end_ns) as u64;
            next += t_ns;
        }
        if t - iv_start >= IV_NS && flush(&mut iv, iv_start, t) {
            iv_start = t;
        }
    }
    let t = now_ns().max(iv_start);
    if let Some(l) = &logs {
        // The last, partial interval: the run is over, a blocking hand-off
        // costs nothing now.
        let (at, len) = (
            Duration::from_nanos(iv_start - start_ns),
            Duration::from_nanos(t - iv_start),
        );
        let _ = l.full.send((at, len, iv));
    }
    out
}

/// Run the timer baseline on every configured core at once.
pub fn timer_baseline(
    cfg: &TimerConfig,
    stop: &AtomicBool,
) -> Result<Vec<CoreTimer>, LatencyError> {
    cfg.validate()?;
    // A common start a little ahead, so every thread is set up in time.
    let start_ns = now_ns() + 20_000_000;
    let start_wall = SystemTime::now() + Duration::from_millis(20);
    let new_log = |core: usize, what: &str| {
        let c = [format!(
            "beliefbus jitter: timer {what}, core {core}, {} Hz, fifo {:?}",
            cfg.rate_hz, cfg.fifo
        )];
        HdrLog::new(start_wall, &c).map_err(|e| LatencyError::Output {
            path: "hdr log".into(),
            reason: e.to_string(),
        })
    };
    std::thread::scope(|s| {
        let mut jobs = Vec::with_capacity(cfg.cores.len());
        for &core in &cfg.cores {
            // The writer is spawned first, from this (unpinned, SCHED_OTHER)
            // thread, so it does not inherit the timer's core or priority.
            let (tx, writer) = if cfg.hdr_logs {
                let logs = [
                    new_log(core, "wake-up latency")?,
                    new_log(core, "period jitter")?,
                ];
                let (full_tx, full_rx) = crossbeam::channel::bounded(POOL + 1);
                let (empty_tx, empty_rx) = crossbeam::channel::bounded(POOL + 1);
                for _ in 0..POOL {
                    let _ = empty_tx.send([LatencyHist::new(), LatencyHist::new()]);
                }
                let w = std::thread::Builder::new()
                    .name(format!("timer-log-{core}"))
                    .spawn_scoped(s, move || log_writer(logs, full_rx, empty_tx))
                    .map_err(|e| LatencyError::Spawn(e.to_string()))?;
                (
                    Some(IntervalTx {
                        full: full_tx,
                        empty: empty_rx,
                    }),
                    Some(w),
                )
            } else {
                (None, None)
            };
            let t = std::thread::Builder::new()
                .name(format!("timer-{core}"))
                .spawn_scoped(s, move || timer_thread(cfg, core, start_ns, stop, tx))
                .map_err(|e| LatencyError::Spawn(e.to_string()))?;
            jobs.push((t, writer));
        }
        let mut out = Vec::with_capacity(jobs.len());
        for (t, w) in jobs {
            let mut c = t
                .join()
                .map_err(|_| LatencyError::Protocol("a timer thread panicked".into()))?;
            if let Some(w) = w {
                let [wake, jit] = w
                    .join()
                    .map_err(|_| LatencyError::Protocol("a log writer panicked".into()))??;
                c.wake_log = Some(wake);
                c.jitter_log = Some(jit);
            }
            out.push(c);
        }
        Ok(out)
    })
}

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
    pub stages: std::collections::BTreeMap<String, super::pipeline::StageFigures>,
    /// The run report's hops (its whole run after warm-up).
    pub hops: serde_json::Value,
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
        s += "(timer rows: jit = |period − T|, lat = wake-up latency, misses = late by a period; pipeline rows: lat = end-to-end (sensor->ingest for sensor), misses = above the budget; r = jitter ratio to the timer)\n";
        if let Some(p) = &self.pipeline {
            s += &format!(
                "pipeline {} at {} Hz: {} controls measured; stage compute vs budget (µs):\n",
                p.config, p.sensor_rate_hz, p.controls
            );
            let o = |x: Option<f64>| x.map(|v| format!("{v:.1}")).unwrap_or_else(|| "-".into());
            for (name, f) in &p.stages {
                s += &format!(
                    "  {:<8} processed {:>8}  compute p50 {:>8} p99 {:>8}  budget {:>8}  misses {:>5}  late {:>5}  lateness p99 {:>8}\n",
                    name,
                    f.processed,
                    o(f.compute_p50_us),
                    o(f.compute_p99_us),
                    o(f.budget_us),
                    f.deadline_misses,
                    f.late,
                    o(f.lateness_p99_us)
                );
            }
        }
        s += &self.load.line();
        s.push('\n');
        for w in &self.warnings {
            s += &format!("warning: {w}\n");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_timer_wakes_once_per_period_never_early() {
        let cfg = TimerConfig {
            rate_hz: 500.0,
            duration: Duration::from_millis(1300),
            cores: vec![0],
            fifo: None,
            hdr_logs: true,
        };
        let stop = AtomicBool::new(false);
        let r = timer_baseline(&cfg, &stop).unwrap();
        assert_eq!(r.len(), 1);
        let c = &r[0];
        // Every period either woke once or was counted as missed.
        assert_eq!(c.wakeups + c.misses, 650, "{} + {}", c.wakeups, c.misses);
        assert_eq!(c.period_jitter.count() + 1, c.wakeups);
        // Never before the deadline (the histogram records ≥ 1 ns).
        assert!(c.wake.count() == c.wakeups);
        // One interval per second, written off the timer thread, plus the
        // last partial one.
        assert_eq!(c.wake_log.as_ref().unwrap().intervals(), 2);
        assert_eq!(c.jitter_log.as_ref().unwrap().intervals(), 2);
        let (merged, per_core) = baseline_entries(&cfg, &r);
        assert_eq!(merged.latency.count, c.wakeups);
        assert_eq!(per_core[0].name, "timer-core0");
        assert_eq!(merged.budget_us, Some(2_000.0));
    }

    #[test]
    fn a_raised_stop_flag_ends_the_baseline_at_once() {
        let cfg = TimerConfig {
            rate_hz: 1000.0,
            duration: Duration::from_secs(3600),
            cores: vec![0],
            fifo: None,
            hdr_logs: false,
        };
        let stop = AtomicBool::new(true);
        let r = timer_baseline(&cfg, &stop).unwrap();
        assert_eq!(r[0].wakeups, 0);
    }

    #[test]
    fn ratios_compare_like_with_like() {
        let mut j = LatencyHist::new();
        let mut l = LatencyHist::new();
        for v in 1..=100u64 {
            j.record(v * 1_000);
            l.record(v * 10_000);
        }
        let base = JitterEntry::new("timer", None, &j, &j, 0, None);
        let e = JitterEntry::new("control", None, &l, &l, 3, Some(1000.0)).with_ratios(&base);
        let r50 = e.ratio_p50.unwrap();
        let r99 = e.ratio_p99.unwrap();
        assert!(
            (r50 - 10.0).abs() < 0.02 && (r99 - 10.0).abs() < 0.02,
            "{r50} {r99}"
        );
        assert!((e.latency_ratio_p99.unwrap() - 10.0).abs() < 0.02);
        let empty =
            JitterEntry::new("x", None, &LatencyHist::new(), &l, 0, None).with_ratios(&base);
        assert_eq!(empty.ratio_p50, None);
        assert!(empty.latency_ratio_p50.is_some());
    }

    #[test]
    fn bad_settings_are_typed_errors() {
        let ok = TimerConfig {
            rate_hz: 1000.0,
            duration: Duration::from_secs(1),
            cores: vec![0],
            fifo: Some(80),
            hdr_logs: false,
        };
        assert!(ok.validate().is_ok());
        for bad in [
            TimerConfig {
                rate_hz: 0.0,
                ..ok.clone()
            },
            TimerConfig {
                rate_hz: f64::NAN,
                ..ok.clone()
            },
            TimerConfig {
                duration: Duration::ZERO,
                ..ok.clone()
            },
            TimerConfig {
                cores: vec![],
                ..ok.clone()
            },
            TimerConfig {
                cores: vec![4096],
                ..ok.clone()
            },
            TimerConfig {
                fifo: Some(0),
                ..ok.clone()
            },
        ] {
            assert!(
                matches!(bad.validate(), Err(LatencyError::BadArg(_))),
                "{bad:?}"
            );
        }
    }
}
