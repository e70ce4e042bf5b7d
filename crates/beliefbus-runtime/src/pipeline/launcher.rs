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

use super::config::{self, ControlBackend};
use super::monitor::Monitor;
use super::report::{ReportInput, StageEnd};
use super::stage_main::BUILD_ID;
use super::supervisor::{Chaos, Death, Decision, GiveUpReason, RestartState};
use super::supervisor_resume::{Resume, ResumeBelief, ResumeControl, ResumeTruth};
use super::supervisor_timeline::{Sample, Timeline};
use super::PipelineConfig;
use crate::ipc::{self, cleanup, Bus, BusConfig, Hop, StageKind};
use crate::rt::clock::now_ns;
use crate::rt::files::{self, PrivateDir};
use anyhow::{bail, Context, Result};
use serde_json::{json, Value};
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

/// Exit status prefix of a stage that died as the run ended, before its
/// restart.
const RESTART_PENDING: &str = "restart pending";
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
    /// When this incarnation was spawned.
    started: Instant,
    restart: RestartState,
    /// A restart is due at this time (no process meanwhile).
    restart_at: Option<Instant>,
    /// The supervisor killed this incarnation for a missed heartbeat.
    hung: bool,
    /// When chaos killed this incarnation (CLOCK_MONOTONIC ns).
    chaos_kill_ns: Option<u64>,
    heartbeat_misses: u64,
    chaos_kills: u64,
    /// Counters of earlier incarnations (processed, dropped, rejected,
    /// deadline misses, late, controls received, processed after warm-up).
    earlier: [u64; 7],
    /// `dropped_by_reason` of earlier incarnations.
    earlier_drops: [u64; crate::ipc::STATS_DROP_REASONS],
    /// Causes of the deaths of earlier incarnations.
    deaths: Vec<String>,
}

/// One death and the recovery that followed it.
#[derive(Debug)]
struct Recovery {
    kind: StageKind,
    cause: String,
    t_death_ns: u64,
    pid: Option<u32>,
    backoff_ms: f64,
    reported_ns: Option<u64>,
    output_ns: Option<u64>,
}

impl Recovery {
    /// Death → recovered (new process reported and an output derived from
    /// post-death data was published), in ms.
    fn ms(&self) -> Option<f64> {
        let done = self.reported_ns?.max(self.output_ns?);
        Some(done.saturating_sub(self.t_death_ns) as f64 / 1e6)
    }
}

fn describe(s: &ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exit {c}"),
        (_, Some(sig)) => format!("signal {sig}"),
        _ => "unknown".into(),
    }
}

/// How to start stage `kind`: its own executable when it is next to us,
/// built from the same sources and the run uses only the built-in
/// scenarios, else our hidden `stage` subcommand (a user's binary with its
/// own registry always runs its stages itself).
fn stage_command(kind: StageKind, builtin: bool) -> Result<(Command, bool)> {
    let me = std::env::current_exe().context("cannot locate the beliefbus executable")?;
    let dir = me.parent().unwrap_or(Path::new("."));
    let exe = dir.join(format!("beliefbus-{}", kind.name()));
    if builtin && exe.is_file() {
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
    state_dir: &Path,
) -> Result<Stage> {
    // A first start gets the run's state directory too (refine checkpoints
    // its chain there from the start; see `supervisor_resume`).
    let first = Resume {
        state_dir: Some(state_dir.to_path_buf()),
        ..Resume::default()
    };
    let path = state_dir.join(format!("{}.resume.json", kind.name()));
    first.save(&path)?;
    let spin = opts.chaos_spin.filter(|(k, _)| *k == kind).map(|(_, t)| t);
    let child = spawn_child(kind, opts, prefix, notes, Some(&path), spin)?;
    eprintln!("supervisor: started {} (pid {})", kind.name(), child.id());
    Ok(Stage {
        kind,
        pid: child.id(),
        child: Some(child),
        exit: None,
        started: Instant::now(),
        restart: RestartState::default(),
        restart_at: None,
        hung: false,
        chaos_kill_ns: None,
        heartbeat_misses: 0,
        chaos_kills: 0,
        earlier: [0; 7],
        earlier_drops: [0; crate::ipc::STATS_DROP_REASONS],
        deaths: Vec::new(),
    })
}

fn spawn_child(
    kind: StageKind,
    opts: &RunOptions,
    prefix: &str,
    notes: &mut Vec<String>,
    resume: Option<&Path>,
    spin_after_s: Option<f64>,
) -> Result<Child> {
    let builtin = opts.registry.as_ref().is_none_or(|r| r.is_builtin());
    let (mut cmd, own) = stage_command(kind, builtin)?;
    if !own && builtin {
        let n = "stage executables next to beliefbus are missing or from another build \
                 (`cargo run` builds only beliefbus); ran the stages as `beliefbus stage <name>`";
        if !notes.iter().any(|x| x == n) {
            notes.push(n.to_string());
        }
    }
    cmd.args(opts.config.stage_args())
        .arg("--prefix")
        .arg(prefix);
    for s in &opts.sets {
        cmd.arg("--set").arg(s);
    }
    if let Some(r) = resume {
        cmd.arg("--resume").arg(r);
    }
    // The stages admit samples on internal channels only from processes
    // whose parent is this launcher (ipc::trust).
    cmd.env(ipc::trust::LAUNCHER_PID_ENV, std::process::id().to_string());
    match spin_after_s {
        Some(t) => cmd.env(crate::rt::sched::SPIN_AFTER_ENV, format!("{t}")),
        None => cmd.env_remove(crate::rt::sched::SPIN_AFTER_ENV),
    };
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
    cmd.spawn()
        .with_context(|| format!("cannot start the {} stage", kind.name()))
}

fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill on a child we spawned and have not reaped yet.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

/// How long the supervisor waits for a SIGKILLed stage to be reaped before
/// it gives up on it (a stage starved of CPU by a runaway SCHED_FIFO stage
/// on its core cannot even die): it never blocks on a child.
const KILL_REAP_TIMEOUT: Duration = Duration::from_secs(2);

impl Stage {
    /// SIGKILL and reap within [`KILL_REAP_TIMEOUT`]; false if it could not
    /// be reaped in that time (the child stays registered, unreaped).
    fn kill_and_reap(&mut self) -> bool {
        signal(self.pid, libc::SIGKILL);
        let deadline = Instant::now() + KILL_REAP_TIMEOUT;
        loop {
            if self.poll_exit() {
                return true;
            }
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

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

/// SIGKILL the hung stage `i` and reap it. A stage that cannot die in
/// [`KILL_REAP_TIMEOUT`] is starved by a real-time stage of higher priority
/// on its core (a runaway that never blocks): escalate by killing that one,
/// the highest-priority such stage first, and reap again. Only when nothing
/// is left to blame does the run end.
fn kill_hung(cfg: &PipelineConfig, stages: &mut [Stage], i: usize) -> Result<()> {
    if stages[i].kill_and_reap() {
        return Ok(());
    }
    let rt = |k: StageKind| cfg.stages.get(k).rt();
    let mine = rt(stages[i].kind);
    let prio = |k: StageKind| rt(k).fifo_priority.unwrap_or(0);
    let mut starvers: Vec<usize> = (0..stages.len())
        .filter(|&j| j != i && stages[j].child.is_some())
        .filter(|&j| {
            let o = rt(stages[j].kind);
            o.core == mine.core && prio(stages[j].kind) > prio(stages[i].kind)
        })
        .collect();
    starvers.sort_by_key(|&j| std::cmp::Reverse(prio(stages[j].kind)));
    for j in starvers {
        eprintln!(
            "supervisor: {} (pid {}) cannot die: killing {} (pid {}, FIFO {} on its core), \
             which starves it",
            stages[i].kind.name(),
            stages[i].pid,
            stages[j].kind.name(),
            stages[j].pid,
            prio(stages[j].kind)
        );
        stages[j].hung = true;
        let killed = stages[j].kill_and_reap();
        if stages[i].kill_and_reap() {
            return Ok(());
        }
        if !killed {
            break;
        }
    }
    bail!(
        "the {} stage (pid {}) did not die within {KILL_REAP_TIMEOUT:?} of SIGKILL, nor after \
         the real-time stages on its core were killed; ending the run",
        stages[i].kind.name(),
        stages[i].pid
    )
}

/// Run the pipeline; returns the report JSON.
pub fn run(opts: &RunOptions, stop: &AtomicBool) -> Result<serde_json::Value, LaunchError> {
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
    let result = supervise(&cfg, opts, &prefix, stop);
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
    let mut json = input.to_json();
    merge_supervision(&mut json, extra);
    print_supervision(&json);
    if let Some(path) = &opts.report {
        let text = serde_json::to_string_pretty(&json).context("serialising the report")?;
        files::replace_file(path, (text + "\n").as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    let failed: Vec<String> = input
        .stages
        .iter()
        .filter(|(k, _)| !(opts.sensor == SensorSource::External && *k == StageKind::Plant))
        .filter(|(_, e)| {
            e.exit.as_deref() != Some("exit 0")
                && !e
                    .exit
                    .as_deref()
                    .is_some_and(|x| x.starts_with(RESTART_PENDING))
        })
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

/// What the supervision loop accumulates for the report.
#[derive(Debug, Default)]
struct Supervision {
    recoveries: Vec<Recovery>,
    dead_nodes_removed: usize,
    chaos_kills: u64,
    timeline: Timeline,
}

fn supervise(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stop: &AtomicBool,
) -> Result<(ReportInput, Vec<String>, Option<anyhow::Error>, Value)> {
    let bus = Bus::open(
        &BusConfig {
            prefix: prefix.to_string(),
            instance: cfg.run.instance.clone(),
        },
        "launcher",
    )?;
    cleanup::check_root(&cleanup::root_path()).map_err(anyhow::Error::msg)?;
    let system = cfg
        .scenario
        .as_ref()
        .map(|s| s.system.clone())
        .context("the config's scenario is unresolved")?;
    let mut mon = Monitor::open(&bus, system, (cfg.run.warmup_s * 1e9) as u64)?;
    if cfg.control.backend == ControlBackend::None {
        mon = mon.beliefs_are_output();
    }
    let mut notes = Vec::new();
    let mut stages: Vec<Stage> = Vec::new();
    // Private (0700, a fresh unpredictable name): resume files and refine's
    // checkpoint are written and read back only there. The run prefix in
    // the name (it carries the launcher's pid) lets a later run sweep the
    // directory of a launcher killed before it could remove its own.
    let state = PrivateDir::create(&format!("{prefix}state."))
        .context("cannot create the run's private state directory")?;
    let state_dir = state.path().to_path_buf();
    let mut sup = Supervision {
        timeline: Timeline::create(opts.timeline.as_deref())
            .with_context(|| "cannot create the timeline file".to_string())?,
        ..Supervision::default()
    };
    let mut ctx = Ctx {
        cfg,
        opts,
        prefix,
        state_dir: &state_dir,
        notes: &mut notes,
        sup: &mut sup,
    };
    let outcome = drive(&mut ctx, stop, &mut mon, &mut stages);
    shutdown(&mut stages, &mut mon);
    let _ = mon.poll();
    drop(state);
    let input = ReportInput {
        scenario: cfg.run.scenario.clone(),
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
                let mut stats = mon.stats(k).copied();
                // Counters span every incarnation; histograms are the last one's.
                if let (Some(st), Some(s)) = (stats.as_mut(), s) {
                    st.processed += s.earlier[0];
                    st.dropped += s.earlier[1];
                    st.rejected += s.earlier[2];
                    st.deadline_misses += s.earlier[3];
                    st.late += s.earlier[4];
                    st.controls_received += s.earlier[5];
                    st.processed_after_warmup += s.earlier[6];
                    for (d, e) in st.dropped_by_reason.iter_mut().zip(s.earlier_drops) {
                        *d += e;
                    }
                }
                (
                    k,
                    StageEnd {
                        // An external plant (`beliefbus plant`) reports its pid.
                        pid: s.map(|s| s.pid).or(mon.stats(k).map(|st| st.pid)),
                        stats,
                        exit: s.and_then(|s| {
                            let e = s.exit.as_ref().map(describe)?;
                            // Died (and was to be restarted) as the run ended.
                            Some(if s.restart_at.is_some() || s.chaos_kill_ns.is_some() {
                                format!("{RESTART_PENDING} ({e})")
                            } else {
                                e
                            })
                        }),
                    },
                )
            })
            .collect(),
        accuracy: mon.accuracy(),
        files_removed: 0,
        files_left: 0,
    };
    let extra = supervision_json(&stages, &sup);
    drop(mon);
    drop(bus);
    Ok((input, notes, outcome.err(), extra))
}

/// The report's supervision figures: `stages.<name>.{restarts,
/// heartbeat_misses, chaos_kills, deaths}` and the `supervisor` section.
fn supervision_json(stages: &[Stage], sup: &Supervision) -> Value {
    let mut per_stage = serde_json::Map::new();
    for s in stages {
        per_stage.insert(
            s.kind.name().into(),
            json!({
                "restarts": s.restart.restarts,
                "heartbeat_misses": s.heartbeat_misses,
                "chaos_kills": s.chaos_kills,
                "deaths": s.deaths,
            }),
        );
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        json!({
            "count": v.len(),
            // Lower median (nearest rank).
            "p50": v.get(v.len().saturating_sub(1) / 2),
            "max": v.last(),
        })
    };
    let mut all: Vec<f64> = sup.recoveries.iter().filter_map(Recovery::ms).collect();
    let mut by_stage = serde_json::Map::new();
    for k in StageKind::ALL {
        let mut v: Vec<f64> = sup
            .recoveries
            .iter()
            .filter(|r| r.kind == k)
            .filter_map(Recovery::ms)
            .collect();
        if !v.is_empty() {
            by_stage.insert(k.name().into(), stats(&mut v));
        }
    }
    json!({
        "stages": per_stage,
        "supervisor": {
            "restarts": stages.iter().map(|s| s.restart.restarts as u64).sum::<u64>(),
            "heartbeat_misses": stages.iter().map(|s| s.heartbeat_misses).sum::<u64>(),
            "chaos_kills": sup.chaos_kills,
            "dead_nodes_removed": sup.dead_nodes_removed,
            "recoveries_pending": sup.recoveries.iter().filter(|r| r.ms().is_none()).count(),
            "recovery_ms": stats(&mut all),
            "recovery_ms_by_stage": by_stage,
            "recoveries": sup.recoveries.iter().map(|r| json!({
                "stage": r.kind.name(),
                "cause": r.cause,
                "backoff_ms": r.backoff_ms,
                "new_pid": r.pid,
                "recovery_ms": r.ms(),
            })).collect::<Vec<_>>(),
        },
        "timeline": sup.timeline.summary(),
    })
}

/// Everything the supervision loop needs besides the stages and monitor.
struct Ctx<'a> {
    cfg: &'a PipelineConfig,
    opts: &'a RunOptions,
    prefix: &'a str,
    state_dir: &'a Path,
    notes: &'a mut Vec<String>,
    sup: &'a mut Supervision,
}

fn exit_death(s: &ExitStatus) -> Death {
    match (s.code(), s.signal()) {
        (Some(c), _) => Death::Exit(c),
        (_, Some(sig)) => Death::Signal(sig),
        _ => Death::Exit(-1),
    }
}

/// A stage incarnation is gone (reaped): account for it and decide.
fn on_death(ctx: &mut Ctx, mon: &mut Monitor, s: &mut Stage) -> Result<()> {
    let death = if s.hung {
        Death::Hang
    } else {
        s.exit.as_ref().map(exit_death).unwrap_or(Death::Exit(-1))
    };
    let chaos = s.chaos_kill_ns.take();
    let t_death_ns = chaos.unwrap_or_else(now_ns);
    let cause = if chaos.is_some() && death == Death::Signal(libc::SIGKILL) {
        "chaos".to_string()
    } else {
        death.describe()
    };
    s.hung = false;
    if let Some(st) = mon.stats(s.kind).filter(|st| st.pid == s.pid) {
        s.earlier[0] += st.processed;
        s.earlier[1] += st.dropped;
        s.earlier[2] += st.rejected;
        s.earlier[3] += st.deadline_misses;
        s.earlier[4] += st.late;
        s.earlier[5] += st.controls_received;
        s.earlier[6] += st.processed_after_warmup;
        for (e, d) in s.earlier_drops.iter_mut().zip(st.dropped_by_reason) {
            *e += d;
        }
    }
    mon.forget(s.kind);
    // iceoryx2 dead-node cleanup: the dead process's node, its ports and
    // data segments (the reaped process no longer holds its lock).
    if let Ok((_, removed, _)) = cleanup::remove_dead_nodes(ctx.prefix) {
        ctx.sup.dead_nodes_removed += removed;
    }
    s.deaths.push(cause.clone());
    let policy = &ctx.cfg.stages.get(s.kind).restart;
    match s.restart.decide(policy, death, s.started.elapsed()) {
        Decision::Restart { after, consecutive } => {
            eprintln!(
                "supervisor: {} (pid {}) died ({cause}); restart #{} in {:.0} ms{}",
                s.kind.name(),
                s.pid,
                s.restart.restarts,
                after.as_secs_f64() * 1e3,
                if consecutive > 1 {
                    format!(" ({consecutive} in a row)")
                } else {
                    String::new()
                }
            );
            s.restart_at = Some(Instant::now() + after);
            ctx.sup.recoveries.push(Recovery {
                kind: s.kind,
                cause,
                t_death_ns,
                pid: None,
                backoff_ms: after.as_secs_f64() * 1e3,
                reported_ns: None,
                output_ns: None,
            });
            Ok(())
        }
        Decision::GiveUp(why) => {
            let why = match why {
                GiveUpReason::PolicyNever => "its restart policy is \"never\"",
                GiveUpReason::CleanExit => "it exited cleanly (restart.on = \"failure\")",
                GiveUpReason::TooManyRestarts => "restart.max_restarts is used up",
                GiveUpReason::Fatal => "it reported an unrecoverable state (its message above)",
            };
            bail!(
                "the {} stage exited unexpectedly ({cause}); not restarted: {why}",
                s.kind.name()
            )
        }
    }
}

/// Start the next incarnation of `s` with what it resumes from.
fn respawn(ctx: &mut Ctx, mon: &Monitor, s: &mut Stage) -> Result<()> {
    let resume = Resume {
        restarts: s.restart.restarts,
        state_dir: Some(ctx.state_dir.to_path_buf()),
        belief: mon.last_belief().map(ResumeBelief::from_msg),
        control: mon.last_control().map(ResumeControl::from_msg),
        truth: mon.last_truth().map(ResumeTruth::from_msg),
    };
    let path = ctx.state_dir.join(format!("{}.resume.json", s.kind.name()));
    resume.save(&path)?;
    let child = spawn_child(s.kind, ctx.opts, ctx.prefix, ctx.notes, Some(&path), None)?;
    s.pid = child.id();
    s.child = Some(child);
    s.exit = None;
    s.started = Instant::now();
    s.restart_at = None;
    eprintln!(
        "supervisor: restarted {} (pid {}, restart #{})",
        s.kind.name(),
        s.pid,
        s.restart.restarts
    );
    if let Some(r) = ctx
        .sup
        .recoveries
        .iter_mut()
        .rev()
        .find(|r| r.kind == s.kind && r.pid.is_none())
    {
        r.pid = Some(s.pid);
    }
    Ok(())
}

fn drive(
    ctx: &mut Ctx,
    stop: &AtomicBool,
    mon: &mut Monitor,
    stages: &mut Vec<Stage>,
) -> Result<()> {
    let (cfg, opts, prefix) = (ctx.cfg, ctx.opts, ctx.prefix);
    // Start everything but the plant, wait for their first reports.
    for &kind in &START_ORDER[..4] {
        stages.push(spawn(kind, opts, prefix, ctx.notes, ctx.state_dir)?);
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
        stages.push(spawn(
            StageKind::Plant,
            opts,
            prefix,
            ctx.notes,
            ctx.state_dir,
        )?);
    } else {
        eprintln!(
            "pipeline up; waiting for sensor samples on {} (prefix {prefix})",
            ipc::service_name(&cfg.run.instance, "sensor")
        );
    }
    let t0 = Instant::now();
    let duration = (cfg.run.duration_s > 0.0).then(|| Duration::from_secs_f64(cfg.run.duration_s));
    let mut next_status = t0 + Duration::from_secs(1);
    let mut chaos = opts.chaos_s.map(|m| {
        let mut c = Chaos::new(m, opts.chaos_seed.unwrap_or(cfg.run.seed));
        let first = t0 + c.next_gap();
        (c, first)
    });
    let period = Duration::from_secs_f64(opts.timeline_period_s.max(0.0));
    let mut next_sample = (opts.timeline_period_s > 0.0).then(|| t0 + period);
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
        // Reap the dead (waitpid) and decide about them.
        for s in stages.iter_mut() {
            if s.restart_at.is_none() && s.poll_exit() {
                on_death(ctx, mon, s)?;
            }
        }
        // Heartbeats: a stage whose last report is overdue hangs.
        let now = Instant::now();
        for i in 0..stages.len() {
            if stages[i].child.is_none() {
                continue;
            }
            let s = &stages[i];
            let (since, limit) = match mon.last_seen(s.kind, s.pid) {
                Some(t) => (
                    t,
                    cfg.stages
                        .get(s.kind)
                        .restart
                        .heartbeat_timeout(cfg.run.stats_period_s),
                ),
                None => (s.started, START_TIMEOUT),
            };
            if now.duration_since(since) > limit {
                let s = &mut stages[i];
                s.heartbeat_misses += 1;
                eprintln!(
                    "supervisor: {} (pid {}) missed its heartbeat deadline ({:.0} ms without a report); killing it",
                    s.kind.name(),
                    s.pid,
                    limit.as_secs_f64() * 1e3
                );
                s.hung = true;
                kill_hung(cfg, stages, i)?;
                for j in 0..stages.len() {
                    if stages[j].restart_at.is_none() && stages[j].poll_exit() {
                        on_death(ctx, mon, &mut stages[j])?;
                    }
                }
            }
        }
        // Restarts that are due.
        for s in stages.iter_mut() {
            if s.restart_at.is_some_and(|t| Instant::now() >= t) {
                respawn(ctx, mon, s)?;
            }
        }
        // Recoveries: the new process reported, and an output derived from
        // data published after the death went out.
        let now_n = now_ns();
        for r in ctx.sup.recoveries.iter_mut().filter(|r| r.ms().is_none()) {
            let Some(pid) = r.pid else { continue };
            if r.reported_ns.is_none() && mon.last_seen(r.kind, pid).is_some() {
                r.reported_ns = Some(now_n);
            }
            if r.output_ns.is_none() {
                r.output_ns = mon
                    .outputs()
                    .iter()
                    .filter(|o| o.t_sensor_pub_ns > r.t_death_ns)
                    .map(|o| o.t_pub_ns)
                    .min();
            }
            if let Some(ms) = r.ms() {
                eprintln!(
                    "supervisor: recovered {} ({}) in {ms:.1} ms",
                    r.kind.name(),
                    r.cause
                );
            }
        }
        // Chaos: SIGKILL a random running stage.
        if let Some((c, at)) = chaos.as_mut() {
            if Instant::now() >= *at {
                *at += c.next_gap();
                let candidates: Vec<usize> = stages
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| {
                        s.child.is_some()
                            && (opts.chaos_stages.is_empty() || opts.chaos_stages.contains(&s.kind))
                    })
                    .map(|(i, _)| i)
                    .collect();
                if let Some(i) = c.pick(candidates.len()) {
                    let s = &mut stages[candidates[i]];
                    eprintln!("supervisor: chaos kills {} (pid {})", s.kind.name(), s.pid);
                    s.chaos_kill_ns = Some(now_ns());
                    s.chaos_kills += 1;
                    ctx.sup.chaos_kills += 1;
                    signal(s.pid, libc::SIGKILL);
                }
            }
        }
        if let Some(at) = next_sample.as_mut() {
            if Instant::now() >= *at {
                *at += period;
                let running: Vec<(StageKind, u32)> = stages
                    .iter()
                    .filter(|s| s.child.is_some())
                    .map(|s| (s.kind, s.pid))
                    .collect();
                let restarts = stages.iter().map(|s| s.restart.restarts as u64).sum();
                let sample = Sample::new(
                    t0.elapsed().as_secs_f64(),
                    &running,
                    cleanup::shm_files(prefix).len(),
                    restarts,
                    &mon.take_window(),
                );
                if !opts.quiet {
                    eprintln!("timeline: {}", sample.to_json());
                }
                ctx.sup.timeline.push(sample);
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

/// Add the supervision figures to the report JSON.
fn merge_supervision(json: &mut Value, extra: Value) {
    if let Some(per) = extra["stages"].as_object() {
        for (name, v) in per {
            if let (Some(dst), Some(src)) = (json["stages"][name].as_object_mut(), v.as_object()) {
                for (k, x) in src {
                    dst.insert(k.clone(), x.clone());
                }
            }
        }
    }
    // Stages the launcher did not start (an external plant): no restarts.
    if let Some(st) = json["stages"].as_object_mut() {
        for v in st.values_mut() {
            if let Some(o) = v.as_object_mut() {
                o.entry("restarts").or_insert(json!(0));
                o.entry("heartbeat_misses").or_insert(json!(0));
            }
        }
    }
    json["supervisor"] = extra["supervisor"].clone();
    json["timeline"] = extra["timeline"].clone();
}

/// One line of supervision figures when anything happened.
fn print_supervision(json: &Value) {
    let s = &json["supervisor"];
    let restarts = s["restarts"].as_u64().unwrap_or(0);
    if restarts > 0 || s["heartbeat_misses"].as_u64().unwrap_or(0) > 0 {
        let f = |v: &Value| v.as_f64().map(|x| format!("{x:.1}")).unwrap_or("-".into());
        println!(
            "supervisor: {restarts} restarts, {} heartbeat misses, {} chaos kills; recovery p50 {} ms, max {} ms over {}",
            s["heartbeat_misses"],
            s["chaos_kills"],
            f(&s["recovery_ms"]["p50"]),
            f(&s["recovery_ms"]["max"]),
            s["recovery_ms"]["count"]
        );
    }
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
                        if !s.kill_and_reap() {
                            eprintln!(
                                "warning: {} (pid {}) was not reaped within {KILL_REAP_TIMEOUT:?} \
                                 of SIGKILL",
                                s.kind.name(),
                                s.pid
                            );
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
