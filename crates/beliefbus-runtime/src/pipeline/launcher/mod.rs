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
//! 4. Print a status line every second; stop on the duration or on Ctrl-C
//!    (SIGINT/SIGTERM). Supervise (policy in [`super::supervisor`]):
//!    reap a dead stage (waitpid), let iceoryx2 remove the dead node's stale
//!    resources, restart it after its backoff with the state it resumes
//!    from ([`super::supervisor_resume`]); kill and restart a stage whose
//!    heartbeat (its statistics report) is overdue; with `--chaos`, kill a
//!    random stage at the configured mean interval. Every death is printed
//!    (`supervisor: …`) and so is every recovery — the first end-to-end
//!    output (control; belief without a controller) derived from a sensor
//!    sample published after the death, once the new process has reported.
//!    A stage whose policy says not to restart ends the run.
//! 5. Stop the plant, then the rest (SIGTERM; SIGKILL after a grace period),
//!    reap every child, collect their final reports, remove every resource
//!    of the prefix (iceoryx2 dead-node cleanup, then the files), print the
//!    tables and write the report.
//!
//! Files: `spawn` (the command line and environment a stage is started
//! with), `supervise` (each stage's bookkeeping and the pure supervision
//! decisions), `run_loop` (the loop that applies them to the processes),
//! `report` (status line, stage ends and supervision figures).

mod report;
mod run_loop;
mod spawn;
mod supervise;

use super::config;
use super::PipelineConfig;
use crate::ipc::{self, cleanup, StageKind};
use crate::rt::files;
use anyhow::Context;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

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
    /// The config file, or a registered scenario's embedded config.
    pub config: config::ConfigSource,
    /// The scenarios to resolve it in (`None`: the built-in ones). With a
    /// registry of its own the launcher starts every stage from this same
    /// executable (`<exe> stage <name>`), which knows that registry.
    pub registry: Option<crate::scenario::Registry>,
    /// `--sensor plant|external`.
    pub sensor: SensorSource,
    /// Overrides `run.duration_s`.
    pub duration_s: Option<f64>,
    pub report: Option<PathBuf>,
    pub sets: Vec<String>,
    /// No status line every second.
    pub quiet: bool,
    /// `--chaos SECONDS`: SIGKILL a random stage at this mean interval.
    pub chaos_s: Option<f64>,
    /// Seed of the chaos schedule (default `run.seed`).
    pub chaos_seed: Option<u64>,
    /// Stages chaos may kill (empty: every stage the launcher started).
    pub chaos_stages: Vec<StageKind>,
    /// `--chaos-spin STAGE:SECONDS`: that stage's first incarnation
    /// busy-loops from then on ([`crate::rt::sched::SPIN_AFTER_ENV`]).
    pub chaos_spin: Option<(StageKind, f64)>,
    /// `--timeline FILE`: one JSON line per period (RSS, shm, latency).
    pub timeline: Option<PathBuf>,
    /// Period of the timeline samples (s; 0: no timeline).
    pub timeline_period_s: f64,
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

/// The validated config of the run, with `--duration` applied.
fn load_config(opts: &RunOptions) -> Result<PipelineConfig, LaunchError> {
    let registry = opts
        .registry
        .clone()
        .unwrap_or_else(crate::scenario::Registry::builtin);
    let mut cfg = opts.config.load(&registry, &opts.sets)?;
    if let Some(d) = opts.duration_s {
        if !(d.is_finite() && d >= 0.0) {
            return Err(config::ConfigError {
                key: "--duration".into(),
                problem: format!("must be >= 0 seconds, got {d}"),
            }
            .into());
        }
        // A duration the supervisor can add to an Instant (never a panic
        // after the stages started).
        config::limits::seconds("--duration", d, config::limits::MAX_DURATION_S)?;
        cfg.run.duration_s = d;
    }
    Ok(cfg)
}

/// Sweep crashed runs, choose the run's prefix (a fresh one, or the
/// config's for external publishers) and announce it.
fn prepare_prefix(cfg: &mut PipelineConfig, opts: &RunOptions) -> String {
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
            cfg.run.scenario,
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
    prefix
}

/// With `run.keep_cores_warm`, idle-class spinners on every core a stage
/// is pinned to, for as long as the guard lives (see [`crate::rt::keep_warm`]).
pub fn keep_warm(cfg: &PipelineConfig) -> Option<crate::rt::KeepWarm> {
    if !cfg.run.keep_cores_warm {
        return None;
    }
    let cores: Vec<usize> = StageKind::ALL
        .iter()
        .filter_map(|&k| cfg.stages.get(k).core)
        .collect();
    let w = crate::rt::KeepWarm::start(&cores);
    for e in w.warnings() {
        eprintln!("warning: {e}");
    }
    Some(w)
}

/// The time the machine took from the stages' cores since `before`
/// (none where no stage is pinned or `/proc/stat` is unreadable).
fn host_report(
    cfg: &PipelineConfig,
    before: &[crate::rt::host::CoreTimes],
) -> Option<crate::pipeline::report::HostReport> {
    let mut cores: Vec<usize> = StageKind::ALL
        .iter()
        .filter_map(|&k| cfg.stages.get(k).core)
        .collect();
    cores.sort_unstable();
    cores.dedup();
    let l = crate::rt::host::loss(before, &crate::rt::host::snapshot(), &cores);
    (!l.is_empty()).then_some(crate::pipeline::report::HostReport { cores: l })
}

/// Run the pipeline; returns the report JSON.
pub fn run(opts: &RunOptions, stop: &AtomicBool) -> Result<serde_json::Value, LaunchError> {
    let mut cfg = load_config(opts)?;
    let prefix = prepare_prefix(&mut cfg, opts);
    let warm = keep_warm(&cfg);
    let host0 = crate::rt::host::snapshot();
    let result = run_loop::supervise(&cfg, opts, &prefix, stop);
    let host = host_report(&cfg, &host0);
    drop(warm);
    // Whatever happened, leave nothing behind.
    let cleaned = cleanup::remove_prefix(&prefix);
    let left = cleanup::resources(&prefix);
    let (mut input, notes, failure, extra) = result?;
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
    let mut rep = input.report();
    report::merge_supervision(&mut rep, extra);
    if let Some(line) = report::supervision_line(&rep) {
        println!("{line}");
    }
    if let Some(h) = &host {
        println!(
            "host: time taken from the stages' cores: {}",
            crate::rt::host::describe(&h.cores)
        );
    }
    rep.host = host;
    let json = serde_json::to_value(&rep).context("serialising the report")?;
    if let Some(path) = &opts.report {
        let text = serde_json::to_string_pretty(&json).context("serialising the report")?;
        files::replace_file(path, (text + "\n").as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    let failed = report::unclean_stages(&input, opts.sensor);
    if let Some(e) = failure {
        return Err(e.into());
    }
    // The filter counted more observations than ingest published: someone
    // else published on the observation channel. The run's figures cannot
    // be trusted, so it fails.
    if let Some((published, counted, unaccounted)) = input.observation_books() {
        if unaccounted < 0 {
            return Err(anyhow::anyhow!(
                "observation accounting went negative: the filter counted {counted} \
                 observations but ingest published {published} (a foreign publisher on \
                 the observation channel?)"
            )
            .into());
        }
    }
    if !failed.is_empty() {
        return Err(anyhow::anyhow!("stage(s) did not stop cleanly: {}", failed.join(", ")).into());
    }
    Ok(json)
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
