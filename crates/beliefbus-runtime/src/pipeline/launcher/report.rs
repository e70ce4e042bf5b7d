//! What the launcher reports: the status line printed every second, each
//! stage's end ([`stage_end`]: counters over every incarnation, how it
//! ended), the supervision figures merged into the run report
//! ([`supervision`], [`merge_supervision`]), the supervision summary
//! line and the stages that did not stop cleanly ([`unclean_stages`]).
//! The run report itself is [`crate::pipeline::report`].

use super::supervise::{describe, Recovery, Stage};
use super::{RunOptions, SensorSource};
use crate::config::ControlBackend;
use crate::ipc::{Hop, StageKind, StageStats};
use crate::pipeline::monitor::Monitor;
use crate::pipeline::report::{
    RecoveryReport, RecoverySummary, ReportInput, RunReport, StageEnd, StageSupervision,
    SupervisorReport,
};
use crate::pipeline::supervisor_timeline::Timeline;
use crate::pipeline::PipelineConfig;
use serde_json::Value;
use std::collections::BTreeMap;
use std::time::Duration;

/// Exit status prefix of a stage that died as the run ended, before its
/// restart.
pub(super) const RESTART_PENDING: &str = "restart pending";

/// What the supervision loop accumulates for the report.
#[derive(Debug, Default)]
pub(super) struct Supervision {
    pub recoveries: Vec<Recovery>,
    pub dead_nodes_removed: usize,
    pub chaos_kills: u64,
    pub timeline: Timeline,
}

/// The end of stage `kind`: `s` is the launcher's record of it (none if
/// the launcher did not start it, e.g. an external plant), `last` its last
/// report.
pub(super) fn stage_end(s: Option<&Stage>, last: Option<StageStats>) -> StageEnd {
    StageEnd {
        // An external plant (`beliefbus plant`) reports its pid.
        pid: s.map(|s| s.pid).or(last.map(|st| st.pid)),
        stats: match s {
            Some(s) => last.map(|st| s.with_earlier(st)),
            None => last,
        },
        exit: s.and_then(|s| {
            let e = s.exit.as_ref().map(describe)?;
            // Died (and was to be restarted) as the run ended.
            Some(if s.restart_at.is_some() || s.chaos_kill_ns.is_some() {
                format!("{RESTART_PENDING} ({e})")
            } else {
                e
            })
        }),
    }
}

/// The report's input at the end of the run that started at
/// `run_start_ns` (CLOCK_MONOTONIC).
pub(super) fn report_input(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stages: &[Stage],
    mon: &Monitor,
    run_start_ns: u64,
) -> ReportInput {
    ReportInput {
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
                (k, stage_end(s, mon.stats(k).copied()))
            })
            .collect(),
        accuracy: mon.accuracy(),
        files_removed: 0,
        files_left: 0,
        run_start_ns,
    }
}

/// The supervision figures of a run: per stage (by name) and the
/// supervisor's section, and the timeline summary.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct SupervisionFigures {
    pub stages: BTreeMap<String, StageSupervision>,
    pub supervisor: SupervisorReport,
    pub timeline: Value,
}

/// The report's supervision figures: `stages.<name>.{restarts,
/// heartbeat_misses, chaos_kills, deaths}` and the `supervisor` section.
pub(super) fn supervision(stages: &[Stage], sup: &Supervision) -> SupervisionFigures {
    let per_stage = stages
        .iter()
        .map(|s| {
            let v = StageSupervision {
                restarts: s.restart.restarts,
                heartbeat_misses: s.heartbeat_misses,
                chaos_kills: Some(s.chaos_kills),
                deaths: Some(s.deaths.clone()),
            };
            (s.kind.name().to_string(), v)
        })
        .collect();
    let times = |k: Option<StageKind>| -> Vec<f64> {
        sup.recoveries
            .iter()
            .filter(|r| k.is_none_or(|k| r.kind == k))
            .filter_map(Recovery::ms)
            .collect()
    };
    let by_stage = StageKind::ALL
        .iter()
        .map(|&k| (k.name().to_string(), times(Some(k))))
        .filter(|(_, v)| !v.is_empty())
        .map(|(k, v)| (k, RecoverySummary::of(v)))
        .collect();
    let recoveries = sup
        .recoveries
        .iter()
        .map(|r| RecoveryReport {
            stage: r.kind.name().to_string(),
            cause: r.cause.clone(),
            backoff_ms: r.backoff_ms,
            new_pid: r.pid,
            recovery_ms: r.ms(),
        })
        .collect();
    SupervisionFigures {
        stages: per_stage,
        supervisor: SupervisorReport {
            restarts: stages.iter().map(|s| s.restart.restarts as u64).sum(),
            heartbeat_misses: stages.iter().map(|s| s.heartbeat_misses).sum(),
            chaos_kills: sup.chaos_kills,
            dead_nodes_removed: sup.dead_nodes_removed,
            recoveries_pending: sup.recoveries.iter().filter(|r| r.ms().is_none()).count(),
            recovery_ms: RecoverySummary::of(times(None)),
            recovery_ms_by_stage: by_stage,
            recoveries,
        },
        timeline: sup.timeline.summary(),
    }
}

/// Add the supervision figures to the report. Stages the launcher did not
/// start (an external plant) get no restarts and no heartbeat misses.
pub(super) fn merge_supervision(report: &mut RunReport, extra: SupervisionFigures) {
    for (name, st) in report.stages.iter_mut() {
        st.supervision = Some(extra.stages.get(name).cloned().unwrap_or_default());
    }
    report.supervisor = Some(extra.supervisor);
    report.timeline = Some(extra.timeline);
}

/// One line of supervision figures when anything happened.
pub(super) fn supervision_line(report: &RunReport) -> Option<String> {
    let s = report.supervisor.as_ref()?;
    if s.restarts == 0 && s.heartbeat_misses == 0 {
        return None;
    }
    let f = |v: Option<f64>| v.map(|x| format!("{x:.1}")).unwrap_or("-".into());
    Some(format!(
        "supervisor: {} restarts, {} heartbeat misses, {} chaos kills; recovery p50 {} ms, max {} ms over {}",
        s.restarts,
        s.heartbeat_misses,
        s.chaos_kills,
        f(s.recovery_ms.p50),
        f(s.recovery_ms.max),
        s.recovery_ms.count
    ))
}

/// The stages that did not stop cleanly, as `name (how)`: neither `exit 0`
/// nor a death pending its restart (an external plant is not ours).
pub(super) fn unclean_stages(input: &ReportInput, sensor: SensorSource) -> Vec<String> {
    input
        .stages
        .iter()
        .filter(|(k, _)| !(sensor == SensorSource::External && *k == StageKind::Plant))
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
        .collect()
}

/// One line: elapsed time, messages per stage, end-to-end latency, error.
pub(super) fn status_line(elapsed: Duration, mon: &Monitor, cfg: &PipelineConfig) -> String {
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

#[cfg(test)]
mod tests;
