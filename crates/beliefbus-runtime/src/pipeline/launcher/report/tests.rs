//! The launcher's report figures built from synthetic stages and recoveries.

use super::*;
use crate::pipeline::monitor::Accuracy;
use serde_json::json;
use std::os::unix::process::ExitStatusExt;
use std::process::ExitStatus;
use std::time::Instant;

fn stage(kind: StageKind, pid: u32) -> Stage {
    Stage::without_process(kind, pid, Instant::now())
}

fn recovery(kind: StageKind, death_ms: u64, done_ms: Option<u64>) -> Recovery {
    Recovery {
        kind,
        cause: "signal 9".into(),
        t_death_ns: death_ms * 1_000_000,
        pid: Some(1),
        backoff_ms: 20.0,
        reported_ns: done_ms.map(|d| d * 1_000_000),
        output_ns: done_ms.map(|d| d * 1_000_000),
    }
}

#[test]
fn stage_end_adds_earlier_counters_and_marks_a_pending_restart() {
    let mut s = stage(StageKind::Filter, 33);
    s.carry(&StageStats {
        processed: 100,
        ..StageStats::default()
    });
    s.exit = Some(ExitStatus::from_raw(libc::SIGKILL));
    s.restart_at = Some(Instant::now());
    let last = StageStats {
        processed: 5,
        pid: 33,
        ..StageStats::default()
    };
    let e = stage_end(Some(&s), Some(last));
    assert_eq!(e.pid, Some(33));
    assert_eq!(e.stats.unwrap().processed, 105);
    assert_eq!(e.exit.as_deref(), Some("restart pending (signal 9)"));
    // A clean exit is reported as is.
    s.restart_at = None;
    s.exit = Some(ExitStatus::from_raw(0));
    assert_eq!(stage_end(Some(&s), None).exit.as_deref(), Some("exit 0"));
    // Not reaped: no exit status.
    s.exit = None;
    assert_eq!(stage_end(Some(&s), None).exit, None);
}

#[test]
fn stage_end_of_a_stage_the_launcher_did_not_start_takes_the_reported_pid() {
    let last = StageStats {
        pid: 4711,
        processed: 9,
        ..StageStats::default()
    };
    let e = stage_end(None, Some(last));
    assert_eq!(e.pid, Some(4711));
    assert_eq!(e.stats.unwrap().processed, 9);
    assert_eq!(e.exit, None);
    assert_eq!(stage_end(None, None).pid, None);
}

#[test]
fn supervision_counts_restarts_and_summarises_recovery_times() {
    let mut f = stage(StageKind::Filter, 1);
    f.restart.restarts = 3;
    f.heartbeat_misses = 1;
    f.chaos_kills = 2;
    f.deaths = vec!["chaos".into(), "hang".into()];
    let mut c = stage(StageKind::Control, 2);
    c.restart.restarts = 1;
    let sup = Supervision {
        // Filter recovered in 30, 10 and 20 ms; control in 50 ms; one
        // filter recovery still pending.
        recoveries: vec![
            recovery(StageKind::Filter, 100, Some(130)),
            recovery(StageKind::Filter, 200, Some(210)),
            recovery(StageKind::Control, 300, Some(350)),
            recovery(StageKind::Filter, 400, Some(420)),
            recovery(StageKind::Filter, 500, None),
        ],
        dead_nodes_removed: 4,
        chaos_kills: 2,
        timeline: Timeline::default(),
    };
    // Through JSON: the keys the report has always had.
    let x = supervision(&[f, c], &sup);
    let per = serde_json::to_value(&x.stages).unwrap();
    assert_eq!(per["filter"]["restarts"], json!(3));
    assert_eq!(per["filter"]["deaths"], json!(["chaos", "hang"]));
    assert_eq!(per["control"]["heartbeat_misses"], json!(0));
    let s = serde_json::to_value(&x.supervisor).unwrap();
    assert_eq!(s["restarts"], json!(4));
    assert_eq!(s["heartbeat_misses"], json!(1));
    assert_eq!(s["chaos_kills"], json!(2));
    assert_eq!(s["dead_nodes_removed"], json!(4));
    assert_eq!(s["recoveries_pending"], json!(1));
    // All four: sorted 10, 20, 30, 50: lower median 20, max 50.
    assert_eq!(
        s["recovery_ms"],
        json!({"count": 4, "p50": 20.0, "max": 50.0})
    );
    assert_eq!(
        s["recovery_ms_by_stage"]["filter"],
        json!({"count": 3, "p50": 20.0, "max": 30.0})
    );
    assert!(s["recovery_ms_by_stage"].get("ingest").is_none());
    assert_eq!(s["recoveries"].as_array().unwrap().len(), 5);
    assert_eq!(s["recoveries"][0]["recovery_ms"], json!(30.0));
    assert!(s["recoveries"][4]["recovery_ms"].is_null());
    assert!(x.timeline.is_null());
    // Empty: count 0 and null figures.
    let none = supervision(&[], &Supervision::default());
    assert_eq!(
        serde_json::to_value(&none.supervisor.recovery_ms).unwrap(),
        json!({"count": 0, "p50": null, "max": null})
    );
}

#[test]
fn merge_adds_supervision_per_stage_and_zero_defaults_for_the_others() {
    let mut report = input_with(&[(StageKind::Filter, None), (StageKind::Plant, None)]).report();
    let mut f = stage(StageKind::Filter, 1);
    f.restart.restarts = 2;
    merge_supervision(&mut report, supervision(&[f], &Supervision::default()));
    let v = serde_json::to_value(&report).unwrap();
    assert_eq!(v["stages"]["filter"]["restarts"], json!(2));
    assert_eq!(v["stages"]["filter"]["chaos_kills"], json!(0));
    assert_eq!(v["stages"]["plant"]["restarts"], json!(0));
    assert_eq!(v["stages"]["plant"]["heartbeat_misses"], json!(0));
    // Not the launcher's: no chaos kills or deaths to report.
    assert!(v["stages"]["plant"].get("deaths").is_none());
    assert_eq!(v["supervisor"]["restarts"], json!(2));
    assert!(v.get("timeline").is_some_and(Value::is_null));
    // Without the launcher's figures neither section is written.
    let plain = serde_json::to_value(input_with(&[]).report()).unwrap();
    assert!(plain.get("supervisor").is_none() && plain.get("timeline").is_none());
}

#[test]
fn supervision_line_only_when_something_happened() {
    let mut quiet = input_with(&[]).report();
    merge_supervision(
        &mut quiet,
        supervision(&[stage(StageKind::Filter, 1)], &Supervision::default()),
    );
    assert_eq!(supervision_line(&quiet), None);
    let mut f = stage(StageKind::Filter, 1);
    f.restart.restarts = 1;
    let sup = Supervision {
        recoveries: vec![recovery(StageKind::Filter, 0, Some(12))],
        ..Supervision::default()
    };
    let mut busy = input_with(&[]).report();
    merge_supervision(&mut busy, supervision(&[f], &sup));
    assert_eq!(
        supervision_line(&busy).as_deref(),
        Some(
            "supervisor: 1 restarts, 0 heartbeat misses, 0 chaos kills; \
             recovery p50 12.0 ms, max 12.0 ms over 1"
        )
    );
}

fn input_with(exits: &[(StageKind, Option<&str>)]) -> ReportInput {
    ReportInput {
        scenario: "ship".into(),
        duration_s: 1.0,
        sensor_rate_hz: 100.0,
        filter_backend: "pf".into(),
        controller: "none".into(),
        sensor_source: "plant".into(),
        prefix: "p".into(),
        stages: exits
            .iter()
            .map(|(k, e)| {
                (
                    *k,
                    StageEnd {
                        pid: None,
                        stats: None,
                        exit: e.map(String::from),
                    },
                )
            })
            .collect(),
        accuracy: Accuracy::default(),
        files_removed: 0,
        files_left: 0,
        run_start_ns: 0,
    }
}

#[test]
fn unclean_stages_are_those_neither_exited_0_nor_pending_a_restart() {
    let i = input_with(&[
        (StageKind::Ingest, Some("exit 0")),
        (StageKind::Filter, Some("restart pending (signal 9)")),
        (StageKind::Control, Some("signal 15")),
        (StageKind::Refine, None),
        (StageKind::Plant, None),
    ]);
    assert_eq!(
        unclean_stages(&i, SensorSource::Plant),
        [
            "control (signal 15)",
            "refine (not reaped)",
            "plant (not reaped)"
        ]
    );
    // An external plant is not the launcher's to stop.
    assert_eq!(
        unclean_stages(&i, SensorSource::External),
        ["control (signal 15)", "refine (not reaped)"]
    );
}
