//! Jitter of the running pipeline: `beliefbus run` is
//! started as a child process on a config, and a monitor of our own reads
//! its `control` stream on a separate, polling subscriber (no listener, so
//! the control stage pays nothing for it). Every figure comes from stamps
//! the messages carry, so the monitor's own polling delay does not enter:
//! - **control period jitter** `|(t_pub,k − t_pub,k−1) − T|` of consecutive
//!   controls (T = 1 / sensor rate); a control period that passes without
//!   a control is a deadline miss (`round(Δ/T) − 1` of them per gap);
//! - **end-to-end latency** `t_control_out − t_sensor_pub` of each control
//!   (the trace), against the end-to-end budget = the sum of the ingest,
//!   filter and control budgets of the config: above it is a deadline miss;
//! - **sensor period jitter** of the plant's publishes (consecutive sensor
//!   sequence numbers in the traces) and its `sensor->ingest` latency.
//!
//! The first `run.warmup_s` seconds of controls are left out (as the run
//! report does); the monitor then measures for the requested duration and
//! closes its port a second before the run ends, so the launcher's cleanup
//! finds no live node of ours in the prefix. The run's stage statistics
//! (per-stage budgets, compute percentiles, deadline misses) come from its
//! report.

use super::stats::PctBlock;
use super::LatencyError;
use crate::ipc::{cleanup, Bus, BusConfig, Control, Hop};
use crate::pipeline::config;
use crate::rt::clock::now_ns;
use crate::rt::LatencyHist;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How to run the pipeline.
#[derive(Clone, Debug)]
pub struct PipelineJitterConfig {
    /// The `beliefbus` executable (its `run` subcommand is used).
    pub exe: PathBuf,
    pub config: PathBuf,
    pub sets: Vec<String>,
    /// Measured time after the warm-up.
    pub duration: Duration,
    /// The config keeps its stages' cores warm (`run.keep_cores_warm`):
    /// these cores; the timer baseline then runs with the same spinners.
    pub warm_cores: Vec<usize>,
}

/// One stage's figures, from the run report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageFigures {
    pub processed: u64,
    /// Inputs received but not processed (superseded, stale, lost, still
    /// queued at shutdown) — for control: beliefs without a control.
    #[serde(default)]
    pub dropped: u64,
    /// The drops by reason (lost, shutdown, stale, superseded), as the run
    /// report counts them.
    #[serde(default)]
    pub dropped_by_reason: std::collections::BTreeMap<String, u64>,
    /// Of the stale drops, those published while the stage was waiting.
    #[serde(default)]
    pub dropped_stale_idle: u64,
    pub deadline_misses: u64,
    /// Of the misses, those during which the stage's own CPU time stayed
    /// within the budget (preempted, not an overrun).
    #[serde(default)]
    pub deadline_misses_preempted: u64,
    /// Of the preempted misses, those during which the stage was never
    /// switched out (interrupts or the hypervisor took the time).
    #[serde(default)]
    pub deadline_misses_host: u64,
    /// Of the misses, those that started in the stage's warm-up (the first
    /// `miss_warmup_s` after its first message) and those after it; the
    /// two add up to `deadline_misses`.
    #[serde(default)]
    pub deadline_misses_warmup: u64,
    #[serde(default)]
    pub deadline_misses_after_warmup: u64,
    #[serde(default)]
    pub miss_warmup_s: f64,
    pub budget_us: Option<f64>,
    pub compute_p50_us: Option<f64>,
    pub compute_p99_us: Option<f64>,
    /// Messages finished after release + budget, and the lateness p99
    /// (response − budget; negative: early).
    pub late: u64,
    pub lateness_p99_us: Option<f64>,
    /// The core the stage was pinned to (null: not pinned).
    #[serde(default)]
    pub core: Option<usize>,
    /// The run report's latest misses of the stage, oldest first (when
    /// each started, on the run's clock and on CLOCK_MONOTONIC, its wall
    /// and CPU time, switches and kind), and how many older ones it no
    /// longer lists.
    #[serde(default)]
    pub misses: Vec<crate::pipeline::report::MissReport>,
    #[serde(default)]
    pub misses_not_listed: u64,
}

/// What the monitor measured.
#[derive(Debug)]
pub struct PipelineJitter {
    pub sensor_rate_hz: f64,
    /// Controls seen in the measured window.
    pub controls: u64,
    pub control_period_jitter: LatencyHist,
    pub control_period_misses: u64,
    pub sensor_to_control: LatencyHist,
    /// Sum of the ingest, filter and control budgets, ns (0: no budget).
    pub e2e_budget_ns: u64,
    pub e2e_misses: u64,
    pub sensor_period_jitter: LatencyHist,
    pub sensor_to_ingest: LatencyHist,
    /// Per stage (`ingest`, `filter`, `control`, `refine`, `plant`).
    pub stages: Vec<(String, StageFigures)>,
    /// `hops` of the run report (percentile blocks in µs).
    pub report_hops: serde_json::Value,
    /// `accuracy` of the run report (estimation error after the warm-up).
    pub report_accuracy: serde_json::Value,
    /// The run report's `host` section (steal and interrupt time per core).
    pub report_host: serde_json::Value,
    /// Shared-memory files of the run left after it ended.
    pub shm_left: usize,
    pub stopped: bool,
}

fn err(m: impl Into<String>) -> LatencyError {
    LatencyError::Protocol(m.into())
}

/// Kills (SIGINT, then SIGKILL) and reaps the run if still alive on drop.
struct RunChild(Option<Child>);

impl RunChild {
    fn wait(&mut self, limit: Duration, interrupt: bool) -> Option<std::process::ExitStatus> {
        let c = self.0.as_mut()?;
        if interrupt {
            // SAFETY: signalling our own child.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGINT) };
        }
        let t = Instant::now();
        loop {
            if let Ok(Some(s)) = c.try_wait() {
                self.0 = None;
                return Some(s);
            }
            if t.elapsed() > limit {
                let _ = c.kill();
                let s = c.wait().ok();
                self.0 = None;
                return s;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for RunChild {
    fn drop(&mut self) {
        self.wait(Duration::from_secs(10), true);
    }
}

/// The prefix the run `pid` created, once its files exist.
fn find_prefix(pid: u32, child: &mut RunChild, stop: &AtomicBool) -> Result<String, LatencyError> {
    let t = Instant::now();
    loop {
        if let Some(p) = cleanup::run_prefixes()
            .into_iter()
            .find(|p| cleanup::run_prefix_pid(p) == Some(pid))
        {
            return Ok(p);
        }
        if let Some(c) = child.0.as_mut() {
            if let Ok(Some(s)) = c.try_wait() {
                return Err(err(format!("beliefbus run exited at start ({s})")));
            }
        }
        if stop.load(Ordering::Relaxed) {
            return Err(err("stopped before the pipeline started"));
        }
        if t.elapsed() > Duration::from_secs(30) {
            return Err(err(
                "the pipeline's shared memory did not appear within 30 s",
            ));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn stage_figures(report: &serde_json::Value) -> Vec<(String, StageFigures)> {
    ["ingest", "filter", "control", "refine", "plant"]
        .iter()
        .filter_map(|&name| {
            let s = report.get("stages")?.get(name)?;
            Some((
                name.to_string(),
                StageFigures {
                    processed: s["processed"].as_u64().unwrap_or(0),
                    dropped: s["dropped"].as_u64().unwrap_or(0),
                    dropped_by_reason: s["dropped_by_reason"]
                        .as_object()
                        .map(|o| {
                            o.iter()
                                .filter_map(|(k, v)| Some((k.clone(), v.as_u64()?)))
                                .collect()
                        })
                        .unwrap_or_default(),
                    dropped_stale_idle: s["dropped_stale_idle"].as_u64().unwrap_or(0),
                    deadline_misses: s["deadline_misses"].as_u64().unwrap_or(0),
                    deadline_misses_preempted: s["deadline_misses_preempted"].as_u64().unwrap_or(0),
                    deadline_misses_host: s["deadline_misses_host"].as_u64().unwrap_or(0),
                    deadline_misses_warmup: s["deadline_misses_warmup"].as_u64().unwrap_or(0),
                    deadline_misses_after_warmup: s["deadline_misses_after_warmup"]
                        .as_u64()
                        .unwrap_or(0),
                    miss_warmup_s: s["miss_warmup_s"].as_f64().unwrap_or(0.0),
                    budget_us: s["budget_us"].as_f64(),
                    compute_p50_us: s["compute_p50_us"].as_f64(),
                    compute_p99_us: s["compute_p99_us"].as_f64(),
                    late: s["late"].as_u64().unwrap_or(0),
                    lateness_p99_us: s["lateness_p99_us"].as_f64(),
                    core: s["core"].as_u64().map(|c| c as usize),
                    misses: serde_json::from_value(s["misses"].clone()).unwrap_or_default(),
                    misses_not_listed: s["misses_not_listed"].as_u64().unwrap_or(0),
                },
            ))
        })
        .collect()
}

/// Run the pipeline and measure it; `stop` ends it early.
pub fn measure(
    cfg: &PipelineJitterConfig,
    stop: &AtomicBool,
) -> Result<PipelineJitter, LatencyError> {
    // Validate exactly as `beliefbus run` will (a bad config: BadArg).
    let pcfg =
        config::load(&cfg.config, &cfg.sets).map_err(|e| LatencyError::BadArg(e.to_string()))?;
    let rate = pcfg.plant.sensor_rate_hz;
    let period_ns = (1e9 / rate).round() as u64;
    let warmup = Duration::from_secs_f64(pcfg.run.warmup_s.max(0.0));
    let e2e_budget_ns = pcfg.stages.ingest.budget_ns()
        + pcfg.stages.filter.budget_ns()
        + pcfg.stages.control.budget_ns();
    // Run long enough for start-up, warm-up, the window and a margin.
    let run_s = warmup.as_secs_f64() + cfg.duration.as_secs_f64() + 2.0;
    // The child's report goes to a private directory of ours: a name in
    // /tmp that another user can predict is a name they can plant a link at.
    let scratch = crate::rt::files::PrivateDir::create("beliefbus-jitter.")
        .map_err(|e| LatencyError::Spawn(format!("cannot create a private directory: {e}")))?;
    let report = scratch.path().join("run-report.json");
    let mut cmd = Command::new(&cfg.exe);
    cmd.arg("run")
        .arg(&cfg.config)
        .arg("--duration")
        .arg(format!("{run_s:.3}"))
        .arg("--quiet")
        .arg("--report")
        .arg(&report);
    for s in &cfg.sets {
        cmd.arg("--set").arg(s);
    }
    // Its tables are not ours to print; its warnings and errors are
    // passed on (all but the line about the temporary report).
    cmd.stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut child = cmd
        .spawn()
        .map_err(|e| LatencyError::Spawn(format!("cannot start beliefbus run: {e}")))?;
    if let Some(err_pipe) = child.stderr.take() {
        let hide = format!("wrote {}", report.display());
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::BufReader::new(err_pipe)
                .lines()
                .map_while(Result::ok)
            {
                if line != hide {
                    eprintln!("pipeline: {line}");
                }
            }
        });
    }
    let pid = child.id();
    let mut child = RunChild(Some(child));
    let prefix = find_prefix(pid, &mut child, stop)?;

    let mut out = PipelineJitter {
        sensor_rate_hz: rate,
        controls: 0,
        control_period_jitter: LatencyHist::new(),
        control_period_misses: 0,
        sensor_to_control: LatencyHist::new(),
        e2e_budget_ns,
        e2e_misses: 0,
        sensor_period_jitter: LatencyHist::new(),
        sensor_to_ingest: LatencyHist::new(),
        stages: Vec::new(),
        report_hops: serde_json::Value::Null,
        report_accuracy: serde_json::Value::Null,
        report_host: serde_json::Value::Null,
        shm_left: 0,
        stopped: false,
    };
    {
        let bus = Bus::open(
            &BusConfig {
                prefix: prefix.clone(),
                instance: pcfg.run.instance.clone(),
            },
            "jitter-monitor",
        )?;
        let sub = bus.subscriber_with::<Control>(256, false)?;
        let mut window: Option<(u64, u64)> = None; // (start, end) ns
        let mut prev: Option<Control> = None;
        let t_start = Instant::now();
        loop {
            if stop.load(Ordering::Relaxed) {
                out.stopped = true;
                break;
            }
            if let Some(c) = child.0.as_mut() {
                if let Ok(Some(s)) = c.try_wait() {
                    child.0 = None;
                    return Err(err(format!("beliefbus run ended early ({s})")));
                }
            }
            let now = now_ns();
            if let Some((_, end)) = window {
                if now >= end {
                    break;
                }
            } else if t_start.elapsed() > Duration::from_secs(60) {
                return Err(err("no control from the pipeline within 60 s"));
            }
            while let Some(c) = sub.receive()? {
                let t = c.header.t_pub_ns;
                let (w0, w1) = *window.get_or_insert_with(|| {
                    let w0 = t + warmup.as_nanos() as u64;
                    (w0, w0 + cfg.duration.as_nanos() as u64)
                });
                if t < w0 || t >= w1 {
                    prev = Some(c);
                    continue;
                }
                out.controls += 1;
                if let Some(e2e) = c.trace.hop_ns(Hop::SensorToControl) {
                    out.sensor_to_control.record(e2e);
                    out.e2e_misses += (e2e_budget_ns > 0 && e2e > e2e_budget_ns) as u64;
                }
                if let Some(si) = c.trace.hop_ns(Hop::SensorToIngest) {
                    out.sensor_to_ingest.record(si);
                }
                if let Some(p) = prev {
                    // Only consecutive controls of the same publisher.
                    if c.header.seq == p.header.seq + 1 && t > p.header.t_pub_ns {
                        let d = t - p.header.t_pub_ns;
                        out.control_period_jitter.record(d.abs_diff(period_ns));
                        let periods = (d as f64 / period_ns as f64).round() as u64;
                        out.control_period_misses += periods.saturating_sub(1);
                    }
                    let (s, ps) = (&c.trace, &p.trace);
                    if s.sensor_channel == ps.sensor_channel
                        && s.sensor_seq == ps.sensor_seq + 1
                        && s.t_sensor_pub_ns > ps.t_sensor_pub_ns
                    {
                        let d = s.t_sensor_pub_ns - ps.t_sensor_pub_ns;
                        out.sensor_period_jitter.record(d.abs_diff(period_ns));
                    }
                }
                prev = Some(c);
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        // The port and node close here, before the run's own cleanup.
    }
    let status = child.wait(Duration::from_secs_f64(run_s + 30.0), out.stopped);
    // Safety net: whatever the run could not remove while we were attached.
    let _ = cleanup::remove_prefix(&prefix);
    out.shm_left = cleanup::resources(&prefix).len();
    let report_json: Option<serde_json::Value> = std::fs::read_to_string(&report)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    let _ = std::fs::remove_file(&report);
    match (status, &report_json) {
        (Some(s), Some(r)) if s.success() || out.stopped => {
            out.stages = stage_figures(r);
            out.report_hops = r["hops"].clone();
            out.report_accuracy = r["accuracy"].clone();
            out.report_host = r["host"].clone();
        }
        (s, _) if !out.stopped => {
            return Err(err(format!(
                "beliefbus run failed ({})",
                s.map(|s| s.to_string())
                    .unwrap_or_else(|| "not reaped".into())
            )));
        }
        _ => {}
    }
    Ok(out)
}

impl PipelineJitter {
    /// The percentile block of the control period jitter.
    pub fn control_block(&self) -> PctBlock {
        PctBlock::of(&self.control_period_jitter)
    }
}

#[cfg(test)]
mod tests {
    use super::stage_figures;

    #[test]
    fn a_stage_s_drops_keep_their_reasons_from_the_run_report() {
        let report = serde_json::json!({"stages": {"control": {
            "processed": 100, "dropped": 4, "dropped_stale_idle": 1,
            "dropped_by_reason": {"lost": 0, "shutdown": 1, "stale": 3, "superseded": 0},
            "deadline_misses": 0, "core": 0
        }}});
        let stages = stage_figures(&report);
        assert_eq!(stages.len(), 1);
        let (name, f) = &stages[0];
        assert_eq!(name, "control");
        assert_eq!(f.dropped, 4);
        assert_eq!(f.dropped_by_reason["stale"], 3);
        assert_eq!(f.dropped_by_reason["shutdown"], 1);
        assert_eq!(f.dropped_by_reason.values().sum::<u64>(), f.dropped);
        assert_eq!(f.dropped_stale_idle, 1);
        assert_eq!(f.core, Some(0));
        assert!(f.misses.is_empty());
    }

    /// The run report's miss list reaches the jitter report whole, and its
    /// text lines give each miss's time on the run's clock and on
    /// CLOCK_MONOTONIC (as a kernel trace prints it).
    #[test]
    fn a_stage_s_listed_misses_come_through_with_their_times() {
        let report = serde_json::json!({"stages": {"ingest": {
            "processed": 10, "deadline_misses": 3, "misses_not_listed": 1,
            "deadline_misses_warmup": 2, "deadline_misses_after_warmup": 1,
            "miss_warmup_s": 1.0,
            "misses": [
                {"t_us": 12345678.4, "t_ns": 8312104233999u64, "wall_us": 115.8,
                 "cpu_us": 116.4, "switches": 0, "minor_faults": 240, "major_faults": 0,
                 "kind": "overrun"},
                {"t_us": 20000001.0, "t_ns": 8319758556000u64, "wall_us": 4331.0,
                 "cpu_us": null, "switches": null, "kind": "host"}
            ]
        }}});
        let stages = stage_figures(&report);
        let f = &stages[0].1;
        assert_eq!(
            f.misses.len() as u64 + f.misses_not_listed,
            f.deadline_misses
        );
        assert_eq!(
            f.deadline_misses_warmup + f.deadline_misses_after_warmup,
            f.deadline_misses
        );
        assert_eq!((f.deadline_misses_warmup, f.miss_warmup_s), (2, 1.0));
        assert_eq!(f.misses[1].kind, "host");
        assert_eq!(f.misses[1].cpu_us, None);
        assert_eq!(f.misses[0].minor_faults, Some(240));
        // A miss written before faults were counted reads as unknown.
        assert_eq!(f.misses[1].minor_faults, None);
        assert_eq!(
            f.misses[0].line("ingest"),
            "ingest miss at t=12.345 678 s (mono 8312.104233 s): 115.8 µs wall, \
             116.4 µs CPU, 0 switches, 240 faults (overrun)\n"
        );
        assert_eq!(
            f.misses[1].line("ingest"),
            "ingest miss at t=20.000 001 s (mono 8319.758556 s): 4331.0 µs wall, \
             CPU time unknown, switches unknown, faults unknown (host)\n"
        );
    }
}
