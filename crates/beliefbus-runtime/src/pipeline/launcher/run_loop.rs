//! The supervision loop over real processes: start the stages, reap and
//! restart the dead, kill the hung, let chaos kill, sample the timeline,
//! stop everything in order. Every decision it applies is taken in
//! [`super::supervise`]; this file only feeds it the processes, the
//! monitor and the clock.

use super::report::{self, Supervision, SupervisionFigures};
use super::spawn::{resume_path, spawn, spawn_child};
use super::supervise::{
    chaos_candidates, describe, give_up_text, heartbeat_overdue, signal, starvers, Recovery, Stage,
    KILL_REAP_TIMEOUT,
};
use super::{RunOptions, SensorSource};
use crate::config::ControlBackend;
use crate::ipc::{self, cleanup, Bus, BusConfig, StageKind};
use crate::pipeline::monitor::Monitor;
use crate::pipeline::report::ReportInput;
use crate::pipeline::supervisor::{Chaos, Decision};
use crate::pipeline::supervisor_resume::{Resume, ResumeBelief, ResumeControl, ResumeTruth};
use crate::pipeline::supervisor_timeline::{Sample, Timeline};
use crate::pipeline::PipelineConfig;
use crate::rt::clock::now_ns;
use crate::rt::files::PrivateDir;
use anyhow::{bail, Context, Result};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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

/// Everything the supervision loop needs besides the stages and monitor.
struct Ctx<'a> {
    cfg: &'a PipelineConfig,
    opts: &'a RunOptions,
    prefix: &'a str,
    state_dir: &'a Path,
    notes: &'a mut Vec<String>,
    sup: &'a mut Supervision,
}

/// What [`supervise`] hands back: the report's input, the notes, the
/// failure that ended the loop (if any) and the supervision figures.
pub(super) type Supervised = (
    ReportInput,
    Vec<String>,
    Option<anyhow::Error>,
    SupervisionFigures,
);

/// Open the bus and monitor on `prefix`, run the stages until the end,
/// stop them and collect what the report needs.
pub(super) fn supervise(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stop: &AtomicBool,
) -> Result<Supervised> {
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
    // The origin of the report's miss times: before the first stage starts.
    let run_start_ns = now_ns();
    let outcome = drive(&mut ctx, stop, &mut mon, &mut stages);
    shutdown(&mut stages, &mut mon);
    let _ = mon.poll();
    drop(state);
    let input = report::report_input(cfg, opts, prefix, &stages, &mon, run_start_ns);
    let extra = report::supervision(&stages, &sup);
    drop(mon);
    drop(bus);
    Ok((input, notes, outcome.err(), extra))
}

/// `(kind, running)` of every stage, for the pure decisions.
fn running(stages: &[Stage]) -> Vec<(StageKind, bool)> {
    stages.iter().map(|s| (s.kind, s.is_running())).collect()
}

/// SIGKILL the hung stage `i` and reap it. A stage that cannot die in
/// [`KILL_REAP_TIMEOUT`] is starved by a real-time stage of higher priority
/// on its core (a runaway that never blocks): escalate by killing that one,
/// the highest-priority such stage first ([`starvers`]), and reap again.
/// Only when nothing is left to blame does the run end.
fn kill_hung(cfg: &PipelineConfig, stages: &mut [Stage], i: usize) -> Result<()> {
    if stages[i].kill_and_reap() {
        return Ok(());
    }
    let rt = |k: StageKind| cfg.stages.get(k).rt();
    for j in starvers(i, &running(stages), rt) {
        eprintln!(
            "supervisor: {} (pid {}) cannot die: killing {} (pid {}, FIFO {} on its core), \
             which starves it",
            stages[i].kind.name(),
            stages[i].pid,
            stages[j].kind.name(),
            stages[j].pid,
            rt(stages[j].kind).fifo_priority.unwrap_or(0)
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

/// A stage incarnation is gone (reaped): account for it and decide.
fn on_death(ctx: &mut Ctx, mon: &mut Monitor, s: &mut Stage) -> Result<()> {
    let t_now_ns = now_ns();
    if let Some(st) = mon.stats(s.kind).filter(|st| st.pid == s.pid) {
        s.carry(st);
    }
    mon.forget(s.kind);
    // iceoryx2 dead-node cleanup: the dead process's node, its ports and
    // data segments (the reaped process no longer holds its lock).
    if let Ok((_, removed, _)) = cleanup::remove_dead_nodes(ctx.prefix) {
        ctx.sup.dead_nodes_removed += removed;
    }
    let policy = &ctx.cfg.stages.get(s.kind).restart;
    let v = s.decide_death(policy, Instant::now(), t_now_ns);
    let cause = v.cause;
    match v.decision {
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
            ctx.sup.recoveries.push(Recovery {
                kind: s.kind,
                cause,
                t_death_ns: v.t_death_ns,
                pid: None,
                backoff_ms: after.as_secs_f64() * 1e3,
                reported_ns: None,
                output_ns: None,
            });
            Ok(())
        }
        Decision::GiveUp(why) => bail!(
            "the {} stage exited unexpectedly ({cause}); not restarted: {}",
            s.kind.name(),
            give_up_text(why)
        ),
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
    let path = resume_path(ctx.state_dir, s.kind);
    resume.save(&path)?;
    let child = spawn_child(s.kind, ctx.opts, ctx.prefix, ctx.notes, Some(&path), None)?;
    s.reincarnated(child.id(), Instant::now());
    s.child = Some(child);
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

/// Start everything but the plant and wait for their first reports.
/// False if a stop signal came first.
fn start_up(
    ctx: &mut Ctx,
    stop: &AtomicBool,
    mon: &mut Monitor,
    stages: &mut Vec<Stage>,
) -> Result<bool> {
    for &kind in &START_ORDER[..4] {
        stages.push(spawn(kind, ctx.opts, ctx.prefix, ctx.notes, ctx.state_dir)?);
    }
    let deadline = Instant::now() + START_TIMEOUT;
    loop {
        mon.poll()?;
        if START_ORDER[..4].iter().all(|&k| mon.stats(k).is_some()) {
            return Ok(true);
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
            return Ok(false);
        }
        if Instant::now() > deadline {
            bail!("stages did not report within {START_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Reap every dead stage not already waiting for its restart, and decide.
fn reap(ctx: &mut Ctx, mon: &mut Monitor, stages: &mut [Stage]) -> Result<()> {
    for s in stages.iter_mut() {
        if s.restart_at.is_none() && s.poll_exit() {
            on_death(ctx, mon, s)?;
        }
    }
    Ok(())
}

/// Heartbeats: a stage whose last report is overdue hangs; kill it.
fn check_heartbeats(ctx: &mut Ctx, mon: &mut Monitor, stages: &mut [Stage]) -> Result<()> {
    let cfg = ctx.cfg;
    let now = Instant::now();
    for i in 0..stages.len() {
        if !stages[i].is_running() {
            continue;
        }
        let s = &stages[i];
        let limit = cfg
            .stages
            .get(s.kind)
            .restart
            .heartbeat_timeout(cfg.run.stats_period_s);
        let seen = mon.last_seen(s.kind, s.pid);
        let Some(limit) = heartbeat_overdue(now, seen, s.started, limit, START_TIMEOUT) else {
            continue;
        };
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
        reap(ctx, mon, stages)?;
    }
    Ok(())
}

/// Recoveries: the new process reported, and an output derived from data
/// published after the death went out.
fn track_recoveries(ctx: &mut Ctx, mon: &Monitor) {
    let now_n = now_ns();
    for r in ctx.sup.recoveries.iter_mut().filter(|r| r.ms().is_none()) {
        let reported = r.pid.is_some_and(|p| mon.last_seen(r.kind, p).is_some());
        if let Some(ms) = r.observe(reported, mon.outputs(), now_n) {
            eprintln!(
                "supervisor: recovered {} ({}) in {ms:.1} ms",
                r.kind.name(),
                r.cause
            );
        }
    }
}

/// Chaos: SIGKILL a random running stage among the allowed ones.
fn chaos_kill(ctx: &mut Ctx, c: &mut Chaos, stages: &mut [Stage]) {
    let candidates = chaos_candidates(&running(stages), &ctx.opts.chaos_stages);
    if let Some(i) = c.pick(candidates.len()) {
        let s = &mut stages[candidates[i]];
        eprintln!("supervisor: chaos kills {} (pid {})", s.kind.name(), s.pid);
        s.chaos_kill_ns = Some(now_ns());
        s.chaos_kills += 1;
        ctx.sup.chaos_kills += 1;
        signal(s.pid, libc::SIGKILL);
    }
}

/// One timeline sample: running processes, shared-memory files, restarts,
/// latency since the previous sample.
fn sample_timeline(ctx: &mut Ctx, mon: &mut Monitor, stages: &[Stage], elapsed_s: f64) {
    let running: Vec<(StageKind, u32)> = stages
        .iter()
        .filter(|s| s.is_running())
        .map(|s| (s.kind, s.pid))
        .collect();
    let restarts = stages.iter().map(|s| s.restart.restarts as u64).sum();
    let sample = Sample::new(
        elapsed_s,
        &running,
        cleanup::shm_files(ctx.prefix).len(),
        restarts,
        &mon.take_window(),
    );
    if !ctx.opts.quiet {
        eprintln!("timeline: {}", sample.to_json());
    }
    ctx.sup.timeline.push(sample);
}

/// Start the stages, then supervise them until the duration is over or a
/// stop signal came.
fn drive(
    ctx: &mut Ctx,
    stop: &AtomicBool,
    mon: &mut Monitor,
    stages: &mut Vec<Stage>,
) -> Result<()> {
    let (cfg, opts, prefix) = (ctx.cfg, ctx.opts, ctx.prefix);
    if !start_up(ctx, stop, mon, stages)? {
        return Ok(());
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
        reap(ctx, mon, stages)?;
        check_heartbeats(ctx, mon, stages)?;
        for s in stages.iter_mut() {
            if s.restart_due(Instant::now()) {
                respawn(ctx, mon, s)?;
            }
        }
        track_recoveries(ctx, mon);
        if let Some((c, at)) = chaos.as_mut() {
            if Instant::now() >= *at {
                *at += c.next_gap();
                chaos_kill(ctx, c, stages);
            }
        }
        if let Some(at) = next_sample.as_mut() {
            if Instant::now() >= *at {
                *at += period;
                sample_timeline(ctx, mon, stages, t0.elapsed().as_secs_f64());
            }
        }
        if !opts.quiet && Instant::now() >= next_status {
            next_status += Duration::from_secs(1);
            eprintln!("{}", report::status_line(t0.elapsed(), mon, cfg));
        }
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
                kill_stragglers(stages, group);
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// SIGKILL and reap the stages of `group` still alive after the grace.
fn kill_stragglers(stages: &mut [Stage], group: &[StageKind]) {
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
}
