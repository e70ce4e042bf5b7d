//! What the launcher reports: the status line printed every second, each
//! stage's end ([`stage_end`]: counters over every incarnation, how it
//! ended), the supervision figures merged into the run report
//! ([`supervision_json`], [`merge_supervision`]), the supervision summary
//! line and the stages that did not stop cleanly ([`unclean_stages`]).
//! The run report itself is [`crate::pipeline::report`].

use super::supervise::{describe, Recovery, Stage};
use super::{RunOptions, SensorSource};
use crate::config::ControlBackend;
use crate::ipc::{Hop, StageKind, StageStats};
use crate::pipeline::monitor::Monitor;
use crate::pipeline::report::{ReportInput, StageEnd};
use crate::pipeline::supervisor_timeline::Timeline;
use crate::pipeline::PipelineConfig;
use serde_json::{json, Value};
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

/// The report's input at the end of the run.
pub(super) fn report_input(
    cfg: &PipelineConfig,
    opts: &RunOptions,
    prefix: &str,
    stages: &[Stage],
    mon: &Monitor,
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
    }
}

/// Count, lower median (nearest rank) and maximum of `v`.
fn summary(v: &mut [f64]) -> Value {
    v.sort_by(f64::total_cmp);
    json!({
        "count": v.len(),
        "p50": v.get(v.len().saturating_sub(1) / 2),
        "max": v.last(),
    })
}

/// The report's supervision figures: `stages.<name>.{restarts,
/// heartbeat_misses, chaos_kills, deaths}` and the `supervisor` section.
pub(super) fn supervision_json(stages: &[Stage], sup: &Supervision) -> Value {
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
            by_stage.insert(k.name().into(), summary(&mut v));
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
            "recovery_ms": summary(&mut all),
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

/// Add the supervision figures to the report JSON.
pub(super) fn merge_supervision(json: &mut Value, extra: Value) {
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
pub(super) fn supervision_line(json: &Value) -> Option<String> {
    let s = &json["supervisor"];
    let restarts = s["restarts"].as_u64().unwrap_or(0);
    if restarts == 0 && s["heartbeat_misses"].as_u64().unwrap_or(0) == 0 {
        return None;
    }
    let f = |v: &Value| v.as_f64().map(|x| format!("{x:.1}")).unwrap_or("-".into());
    Some(format!(
        "supervisor: {restarts} restarts, {} heartbeat misses, {} chaos kills; recovery p50 {} ms, max {} ms over {}",
        s["heartbeat_misses"],
        s["chaos_kills"],
        f(&s["recovery_ms"]["p50"]),
        f(&s["recovery_ms"]["max"]),
        s["recovery_ms"]["count"]
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
