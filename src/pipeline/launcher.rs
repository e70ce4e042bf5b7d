//! `beliefbus run`: validate the config, give the run its own shared-memory
//! prefix, spawn the five stage processes, watch them, stop them, leave
//! nothing behind, report.
//!
//! 1. Load and validate the whole config (a bad one: exit 2, one line).
//! 2. Remove what crashed earlier runs left ([`cleanup::sweep_stale_runs`]),
//!    make a fresh prefix and open the monitor on it.
//!    With `--sensor external` the run uses the config's `run.prefix`
//!    instead (external publishers must know it; `docs/sensor-abi.md`),
//!    after removing what dead participants left on it, and prints it.
//! 3. Spawn `beliefbus-<stage>` found next to this executable (if it was
//!    built from the same sources; otherwise this executable's hidden
//!    `stage <name>` subcommand runs the same code), downstream first:
//!    control, refine, filter, ingest — each in its own process group, with
//!    SIGTERM as its parent-death signal — and the plant once the others
//!    have reported (not with `--sensor external`: then external
//!    publishers, e.g. `beliefbus plant`, feed the pipeline). Each stage pins and prioritises itself from
//!    `[stages.<name>]`.
//! 4. Print a status line every second; stop on the duration, on Ctrl-C
//!    (SIGINT/SIGTERM) or when a stage dies.
//! 5. Stop the plant, then the rest (SIGTERM; SIGKILL after a grace period),
//!    reap every child, collect their final reports, remove every resource
//!    of the prefix (iceoryx2 dead-node cleanup, then the files), print the
//!    tables and write the report.

use super::config::{self, ControlBackend};
use super::monitor::Monitor;
use super::report::{ReportInput, StageEnd};
use super::stage_main::BUILD_ID;
use super::PipelineConfig;
use crate::ipc::{self, cleanup, Bus, BusConfig, Hop, StageKind};
use anyhow::{bail, Context, Result};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Where the sensor samples of a run come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SensorSource {
    /// The built-in simulated plant (a stage process of the run).
    #[default]
    Plant,
    /// External publishers (`docs/sensor-abi.md`): no plant is started; the
    /// run uses the config's `run.prefix` so publishers know it in advance.
    External,
}

/// Options of `beliefbus run`.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    pub config: PathBuf,
    /// `--sensor plant|external`.
    pub sensor: SensorSource,
    /// Overrides `run.duration_s`.
    pub duration_s: Option<f64>,
    pub report: Option<PathBuf>,
    pub sets: Vec<String>,
    /// No status line every second.
    pub quiet: bool,
}

/// Why the launcher failed (the binary maps it to an exit status).
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// Bad config or options: exit 2.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// Anything else: exit 1.
    #[error(transparent)]
    Runtime(#[from] anyhow::Error),
}

/// Grace period for a stage to stop after SIGTERM.
const STOP_GRACE: Duration = Duration::from_secs(5);
/// Time for all stages but the plant to come up.
const START_TIMEOUT: Duration = Duration::from_secs(20);
/// Monitor poll period.
const POLL: Duration = Duration::from_millis(10);

/// Start order: consumers before producers, so no early data is lost.
const START_ORDER: [StageKind; 5] = [
    StageKind::Control,
    StageKind::Refine,
    StageKind::Filter,
    StageKind::Ingest,
    StageKind::Plant,
];

struct Stage {
    kind: StageKind,
    child: Option<Child>,
    pid: u32,
    exit: Option<ExitStatus>,
}

fn describe(s: &ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exit {c}"),
        (_, Some(sig)) => format!("signal {sig}"),
        _ => "unknown".into(),
    }
}

/// How to start stage `kind`: its own executable when it is next to us and
/// built from the same sources, else our hidden `stage` subcommand.
fn stage_command(kind: StageKind) -> Result<(Command, bool)> {
    let me = std::env::current_exe().context("cannot locate the beliefbus executable")?;
    let dir = me.parent().unwrap_or(Path::new("."));
    let exe = dir.join(format!("beliefbus-{}", kind.name()));
    if exe.is_file() {
        let same = Command::new(&exe)
            .arg("--build-id")
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim() == BUILD_ID)
            .unwrap_or(false);
        if same {
            return Ok((Command::new(exe), true));
        }
    }
    let mut c = Command::new(me);
    c.arg("stage").arg(kind.name());
    Ok((c, false))
}

fn spawn(
    kind: StageKind,
    opts: &RunOptions,
    prefix: &str,
    notes: &mut Vec<String>,
) -> Result<Stage> {
    let (mut cmd, own) = stage_command(kind)?;
    if !own {
        let n = "stage executables next to beliefbus are missing or from another build \
                 (`cargo run` builds only beliefbus); ran the stages as `beliefbus stage <name>`";
        if !notes.iter().any(|x| x == n) {
            notes.push(n.to_string());
        }
    }
    cmd.arg(&opts.config).arg("--prefix").arg(prefix);
    for s in &opts.sets {
        cmd.arg("--set").arg(s);
    }
    // Own process group: a terminal's Ctrl-C reaches only the launcher, which
    // stops the stages in order. Parent-death signal: if the launcher dies,
    // the stages stop too (and release their shared memory).
    cmd.process_group(0);
    // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start the {} stage", kind.name()))?;
    Ok(Stage {
        kind,
        pid: child.id(),
        child: Some(child),
        exit: None,
    })
}

fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill on a child we spawned and have not reaped yet.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

impl Stage {
    /// Reap if exited; true if it has.
    fn poll_exit(&mut self) -> bool {
        if self.exit.is_some() {
            return true;
        }
        if let Some(c) = self.child.as_mut() {
            if let Ok(Some(s)) = c.try_wait() {
                self.exit = Some(s);
                self.child = None;
                return true;
            }
        }
        false
    }
}

/// Run the pipeline; returns the report JSON.
pub fn run(opts: &RunOptions, stop: &AtomicBool) -> Result<serde_json::Value, LaunchError> {
    let mut cfg = config::load(&opts.config, &opts.sets)?;
    if let Some(d) = opts.duration_s {
        if !(d.is_finite() && d >= 0.0) {
            return Err(config::ConfigError {
                key: "--duration".into(),
                problem: format!("must be >= 0 seconds, got {d}"),
            }
            .into());
        }
        cfg.run.duration_s = d;
    }
    let swept = cleanup::sweep_stale_runs();
    if !swept.is_empty() {
        eprintln!(
            "removed shared memory of {} crashed earlier run(s)",
            swept.len()
        );
    }
    let prefix = match opts.sensor {
        SensorSource::Plant => cleanup::run_prefix(),
        SensorSource::External => {
            // A known prefix; what dead participants left on it goes first
            // (live external publishers are left alone).
            let _ = cleanup::remove_prefix(&cfg.run.prefix);
            cfg.run.prefix.clone()
        }
    };
    cfg.run.prefix = prefix.clone();
    if !opts.quiet {
        eprintln!(
            "beliefbus: {} ({} Hz, filter {}, control {}) under shared-memory prefix {prefix}",
            cfg.run.scenario.name(),
            cfg.plant.sensor_rate_hz,
            cfg.filter.backend.name(),
            cfg.control.backend.name()
        );
    }
    // Always printed (also with --quiet): external publishers need it.
    eprintln!(
        "bus: prefix={prefix} instance={} sensor={}{}",
        cfg.run.instance,
        ipc::service_name(&cfg.run.instance, "sensor"),
        if opts.sensor == SensorSource::External {
            " (external publishers; see docs/sensor-abi.md)"
        } else {
            ""
        }
    );
    let result = supervise(&cfg, opts, &prefix, stop);
    // Whatever happened, leave nothing behind.
    let cleaned = cleanup::remove_prefix(&prefix);
    let left = cleanup::resources(&prefix);
    let (mut input, notes, failure) = result?;
    input.files_removed = cleaned.map(|r| r.files_removed).unwrap_or(0);
    input.files_left = left.len();
    for n in notes {
        eprintln!("note: {n}");
    }
    print!("{}", input.render());
    if !left.is_empty() {
        eprintln!(
            "warning: {} shared-memory file(s) of the run could not be removed",
            left.len()
        );
    }
    let json = input.to_json();
    if let Some(path) = &opts.report {
        let text = serde_json::to_string_pretty(&json).context("serialising the report")?;
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    let failed: Vec<String> = input
        .stages
        .iter()
        .filter(|(k, _)| !(opts.sensor == SensorSource::External && *k == StageKind::Plant))
        .filter(|(_, e)| e.exit.as_deref() != Some("exit 0"))
        .map(|(k, e)| {
            format!(
                "{} ({})",
                k.name(),
                e.exit.clone().unwrap_or("not reaped".into())
            )
        })
        .collect();
    if let Some(e) = failure {
        return Err(e.into());
    }
    if !failed.is_empty() {
        return Err(anyhow::anyhow!("stage(s) did not stop cleanly: {}", failed.join(", ")).into());
    }
    Ok(json)
}

fn supervise(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stop: &AtomicBool,
) -> Result<(ReportInput, Vec<String>, Option<anyhow::Error>)> {
    let bus = Bus::open(
        &BusConfig {
            prefix: prefix.to_string(),
            instance: cfg.run.instance.clone(),
        },
        "launcher",
    )?;
    let model = cfg.model()?;
    let mut mon = Monitor::open(&bus, model, (cfg.run.warmup_s * 1e9) as u64)?;
    let mut notes = Vec::new();
    let mut stages: Vec<Stage> = Vec::new();
    let outcome = drive(cfg, opts, prefix, stop, &mut mon, &mut stages, &mut notes);
    shutdown(&mut stages, &mut mon);
    let _ = mon.poll();
    let input = ReportInput {
        scenario: cfg.run.scenario.name().into(),
        duration_s: cfg.run.duration_s,
        sensor_rate_hz: cfg.plant.sensor_rate_hz,
        filter_backend: cfg.filter.backend.name().into(),
        controller: cfg.control.backend.name().into(),
        sensor_source: match opts.sensor {
            SensorSource::Plant => "plant",
            SensorSource::External => "external",
        }
        .into(),
        prefix: prefix.to_string(),
        stages: StageKind::ALL
            .iter()
            .map(|&k| {
                let s = stages.iter().find(|s| s.kind == k);
                (
                    k,
                    StageEnd {
                        // An external plant (`beliefbus plant`) reports its pid.
                        pid: s.map(|s| s.pid).or(mon.stats(k).map(|st| st.pid)),
                        stats: mon.stats(k).copied(),
                        exit: s.and_then(|s| s.exit.as_ref()).map(describe),
                    },
                )
            })
            .collect(),
        accuracy: mon.accuracy(),
        files_removed: 0,
        files_left: 0,
    };
    drop(mon);
    drop(bus);
    Ok((input, notes, outcome.err()))
}

fn drive(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stop: &AtomicBool,
    mon: &mut Monitor,
    stages: &mut Vec<Stage>,
    notes: &mut Vec<String>,
) -> Result<()> {
    // Start everything but the plant, wait for their first reports.
    for &kind in &START_ORDER[..4] {
        stages.push(spawn(kind, opts, prefix, notes)?);
    }
    let deadline = Instant::now() + START_TIMEOUT;
    loop {
        mon.poll()?;
        if START_ORDER[..4].iter().all(|&k| mon.stats(k).is_some()) {
            break;
        }
        for s in stages.iter_mut() {
            if s.poll_exit() {
                bail!(
                    "the {} stage exited during start-up ({})",
                    s.kind.name(),
                    s.exit.as_ref().map(describe).unwrap_or_default()
                );
            }
        }
        if stop.load(Ordering::Relaxed) {
            eprintln!("stopping (signal)");
            return Ok(());
        }
        if Instant::now() > deadline {
            bail!("stages did not report within {START_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    // Let every waiting stage connect to the publishers that appeared after
    // it (they refresh their connections when idle), so no first sample is
    // lost.
    std::thread::sleep(3 * ipc::STOP_POLL);
    if opts.sensor == SensorSource::Plant {
        stages.push(spawn(StageKind::Plant, opts, prefix, notes)?);
    } else {
        eprintln!(
            "pipeline up; waiting for sensor samples on {} (prefix {prefix})",
            ipc::service_name(&cfg.run.instance, "sensor")
        );
    }
    let t0 = Instant::now();
    let duration = (cfg.run.duration_s > 0.0).then(|| Duration::from_secs_f64(cfg.run.duration_s));
    let mut next_status = t0 + Duration::from_secs(1);
    loop {
        std::thread::sleep(POLL);
        mon.poll()?;
        if stop.load(Ordering::Relaxed) {
            eprintln!("stopping (signal)");
            return Ok(());
        }
        if duration.is_some_and(|d| t0.elapsed() >= d) {
            return Ok(());
        }
        for s in stages.iter_mut() {
            // Refine is anytime work: the filter keeps its last chain, so
            // losing it does not stop the run (issue 4).
            if s.kind == StageKind::Refine && s.exit.is_some() {
                continue;
            }
            if s.poll_exit() {
                if s.kind == StageKind::Refine {
                    eprintln!(
                        "warning: the refine stage exited ({}); filtering goes on with the last chain",
                        s.exit.as_ref().map(describe).unwrap_or_default()
                    );
                    continue;
                }
                bail!(
                    "the {} stage exited unexpectedly ({})",
                    s.kind.name(),
                    s.exit.as_ref().map(describe).unwrap_or_default()
                );
            }
        }
        if !opts.quiet && Instant::now() >= next_status {
            next_status += Duration::from_secs(1);
            eprintln!("{}", status_line(t0.elapsed(), mon, cfg));
        }
    }
}

/// One line: elapsed time, messages per stage, end-to-end latency, error.
fn status_line(elapsed: Duration, mon: &Monitor, cfg: &PipelineConfig) -> String {
    let n = |k| mon.stats(k).map(|s| s.processed).unwrap_or(0);
    // External sensors: what reached ingest (accepted + rejected).
    let sensor = mon
        .stats(StageKind::Plant)
        .map(|s| s.processed)
        .or(mon
            .stats(StageKind::Ingest)
            .map(|s| s.processed + s.rejected))
        .unwrap_or(0);
    let mut line = format!(
        "[{:>4.0}s] sensor {} ingest {} filter {} control {} refine {}",
        elapsed.as_secs_f64(),
        sensor,
        n(StageKind::Ingest),
        n(StageKind::Filter),
        n(StageKind::Control),
        n(StageKind::Refine),
    );
    let hop = if cfg.control.backend == ControlBackend::None {
        (Hop::SensorToBelief, StageKind::Filter)
    } else {
        (Hop::SensorToControl, StageKind::Control)
    };
    if let Some(p) = mon.stats(hop.1).and_then(|s| s.hop(hop.0)) {
        if p.count > 0 {
            line.push_str(&format!(
                " | {} p50 {:.0} µs p99 {:.0} µs",
                hop.0.key(),
                p.p50_ns as f64 / 1e3,
                p.p99_ns as f64 / 1e3
            ));
        }
    }
    let a = mon.accuracy();
    if let (Some(r), Some(raw)) = (a.rmse_position, a.rmse_position_raw) {
        line.push_str(&format!(" | rmse {r:.3} (raw {raw:.3})"));
    }
    let rejected: u64 = StageKind::ALL
        .iter()
        .filter_map(|&k| mon.stats(k))
        .map(|s| s.rejected)
        .sum();
    if rejected > 0 {
        line.push_str(&format!(" | rejected {rejected}"));
    }
    line
}

/// Stop the plant, then the rest; reap everything; SIGKILL stragglers.
fn shutdown(stages: &mut [Stage], mon: &mut Monitor) {
    let order = [
        &[StageKind::Plant][..],
        &[
            StageKind::Ingest,
            StageKind::Filter,
            StageKind::Control,
            StageKind::Refine,
        ][..],
    ];
    for group in order {
        for s in stages.iter_mut().filter(|s| group.contains(&s.kind)) {
            if !s.poll_exit() {
                signal(s.pid, libc::SIGTERM);
            }
        }
        let deadline = Instant::now() + STOP_GRACE;
        loop {
            let _ = mon.poll();
            // Poll every stage (reaping each that exited), not just the first.
            let mut all = true;
            for s in stages.iter_mut().filter(|s| group.contains(&s.kind)) {
                all &= s.poll_exit();
            }
            if all {
                break;
            }
            if Instant::now() > deadline {
                for s in stages.iter_mut().filter(|s| group.contains(&s.kind)) {
                    if !s.poll_exit() {
                        eprintln!(
                            "warning: {} did not stop in {STOP_GRACE:?}; killing it",
                            s.kind.name()
                        );
                        signal(s.pid, libc::SIGKILL);
                        if let Some(mut c) = s.child.take() {
                            s.exit = c.wait().ok();
                        }
                    }
                }
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Entry of `beliefbus run`: installs the stop handler, runs, maps errors to
/// exit statuses (2: config, 1: runtime).
pub fn main(opts: &RunOptions) -> i32 {
    let stop = ipc::install_stop_handler();
    match run(opts, stop) {
        Ok(_) => 0,
        Err(LaunchError::Config(e)) => {
            eprintln!("beliefbus: {e}");
            2
        }
        Err(LaunchError::Runtime(e)) => {
            eprintln!("beliefbus: {e:#}");
            1
        }
    }
}
