//! The run report from synthetic stage statistics.

use super::*;
use crate::ipc::HopStats;
use serde_json::json;

fn input() -> ReportInput {
    let mut ctl = StageStats {
        stage: StageKind::Control as u32,
        processed: 10,
        budget_ns: 700_000,
        late: 2,
        response_p50_ns: 400_000,
        response_p99_ns: 750_000,
        response_max_ns: 900_000,
        ..StageStats::default()
    };
    ctl.hops[0] = HopStats {
        hop: Hop::SensorToControl as u32,
        reserved: 0,
        pct: Percentiles {
            count: 9,
            p50_ns: 1_500,
            p90_ns: 2_000,
            p99_ns: 3_000,
            p999_ns: 4_000,
            max_ns: 5_000,
        },
    };
    ReportInput {
        scenario: "ship".into(),
        duration_s: 1.0,
        sensor_rate_hz: 100.0,
        filter_backend: "pf".into(),
        controller: "mppi".into(),
        sensor_source: "plant".into(),
        prefix: "p".into(),
        stages: StageKind::ALL
            .iter()
            .map(|&k| {
                (
                    k,
                    StageEnd {
                        pid: Some(k as u32),
                        stats: (k == StageKind::Control).then_some(ctl),
                        exit: Some("exit 0".into()),
                    },
                )
            })
            .collect(),
        accuracy: Accuracy::default(),
        files_removed: 3,
        files_left: 0,
        run_start_ns: 5_000_000_000,
    }
}

#[test]
fn json_has_every_documented_key() {
    let v = input().to_json();
    for k in [
        "scenario",
        "duration_s",
        "sensor_rate_hz",
        "filter_backend",
        "controller",
        "hops",
        "stages",
        "accuracy",
        "control",
    ] {
        assert!(v.get(k).is_some(), "missing {k}");
    }
    for h in Hop::ALL {
        let hop = &v["hops"][h.key()];
        for k in ["count", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"] {
            assert!(hop.get(k).is_some(), "hops.{}.{k}", h.key());
        }
    }
    assert_eq!(v["hops"]["sensor->control"]["p50_us"], json!(1.5));
    assert_eq!(v["hops"]["sensor->control"]["count"], json!(9));
    // Lateness = response − budget, negative when early; null without data.
    let c = &v["stages"]["control"];
    assert_eq!(c["late"], json!(2));
    assert_eq!(c["lateness_p50_us"], json!(-300.0));
    assert_eq!(c["lateness_p99_us"], json!(50.0));
    assert_eq!(c["lateness_max_us"], json!(200.0));
    assert!(v["stages"]["filter"]["lateness_p99_us"].is_null());
    for s in StageKind::ALL {
        let st = &v["stages"][s.name()];
        for k in [
            "pid",
            "core",
            "processed",
            "dropped",
            "rejected",
            "deadline_misses",
            "deadline_misses_preempted",
            "deadline_misses_host",
            "deadline_misses_warmup",
            "deadline_misses_after_warmup",
            "miss_warmup_s",
            "dropped_stale_idle",
            "compute_p50_us",
            "compute_p99_us",
            "budget_us",
            "late",
            "lateness_p50_us",
            "lateness_p99_us",
            "lateness_max_us",
            "misses",
            "misses_not_listed",
        ] {
            assert!(st.get(k).is_some(), "stages.{}.{k}", s.name());
        }
    }
    for k in ["rmse_position", "rmse_state", "rmse_position_raw"] {
        assert!(v["accuracy"].get(k).is_some());
    }
    for k in ["waypoints_reached", "mean_distance_to_waypoint"] {
        assert!(v["control"].get(k).is_some());
    }
    for k in [
        "versions",
        "states",
        "delta_s",
        "swap_p50_us",
        "swap_p99_us",
        "mass_lost_max",
        "fallback_steps",
        "fallback_episodes",
        "fallback_reinits",
        "stale_max_ms",
    ] {
        assert!(v["chain"].get(k).is_some(), "chain.{k}");
    }
    assert!(v["stages"]["ingest"]["rejected_by_reason"]
        .get("non_finite")
        .is_some());
}

#[test]
fn control_section_has_controller_cost_and_compute_percentiles() {
    let mut inp = input();
    let v = inp.to_json();
    assert_eq!(v["control"]["controller"], json!("mppi"));
    // No control data yet: null, not zero.
    for k in ["cost", "compute_p50_us", "compute_p99_us"] {
        assert!(v["control"][k].is_null(), "{k}");
    }
    let (_, end) = inp
        .stages
        .iter_mut()
        .find(|(k, _)| *k == StageKind::Control)
        .unwrap();
    let s = end.stats.as_mut().unwrap();
    s.control_cost = 12.5;
    s.control_cost_time_s = 3.0;
    s.compute = Percentiles {
        count: 10,
        p50_ns: 250_000,
        p90_ns: 300_000,
        p99_ns: 420_000,
        p999_ns: 500_000,
        max_ns: 600_000,
    };
    let v = inp.to_json();
    assert_eq!(v["control"]["cost"], json!(12.5));
    assert_eq!(v["control"]["compute_p50_us"], json!(250.0));
    assert_eq!(v["control"]["compute_p99_us"], json!(420.0));
}

#[test]
fn render_lists_every_hop_and_stage() {
    let t = input().render();
    for h in Hop::ALL {
        assert!(t.contains(h.key()));
    }
    for s in StageKind::ALL {
        assert!(t.contains(s.name()));
    }
}

#[test]
fn a_written_report_parses_back_with_its_schema_version_and_every_field() {
    let mut inp = input();
    inp.accuracy = Accuracy {
        rmse_position: Some(0.25),
        rmse_state: Some(f64::NAN),
        rmse_position_raw: Some(1.5),
        beliefs: 90,
        samples: 100,
        scenario: Some(json!({"tracking_mse": 1.5})),
    };
    let report = inp.report();
    // Written as `beliefbus run --report` writes it, then read back.
    let dir = crate::rt::files::PrivateDir::create("beliefbus-report-test.").unwrap();
    let path = dir.path().join("report.json");
    let text = serde_json::to_string_pretty(&inp.to_json()).unwrap();
    crate::rt::files::replace_file(&path, (text + "\n").as_bytes()).unwrap();
    let back = std::fs::read_to_string(&path).unwrap();
    let v: serde_json::Value = serde_json::from_str(&back).unwrap();
    assert_eq!(v["schema_version"], json!(REPORT_SCHEMA_VERSION));
    assert!(v["schema_version"].is_u64());
    let parsed: RunReport = serde_json::from_str(&back).unwrap();
    assert_eq!(parsed.schema_version, 1);
    assert_eq!(parsed.scenario, "ship");
    assert_eq!(parsed.controller, "mppi");
    assert_eq!(parsed.hops["sensor->control"].p50_us, Some(1.5));
    assert_eq!(parsed.hops["sensor->ingest"], HopJson::default());
    assert_eq!(parsed.stages["control"].lateness_p99_us, Some(50.0));
    assert_eq!(
        parsed.stages["control"].exit_status.as_deref(),
        Some("exit 0")
    );
    assert_eq!(parsed.accuracy.rmse_position, Some(0.25));
    // A non-finite figure is written as null.
    assert_eq!(parsed.accuracy.rmse_state, None);
    assert_eq!(parsed.shared_memory.files_removed, 3);
    // The scenario's own section, keyed by its name; a report without
    // one (an older writer, or a scenario without figures) still parses.
    assert_eq!(parsed.scenario_metrics["ship"]["tracking_mse"], 1.5);
    let mut older = v.clone();
    older.as_object_mut().unwrap().remove("scenario_metrics");
    let o: RunReport = serde_json::from_value(older).unwrap();
    assert!(o.scenario_metrics.is_empty());
    // Nothing lost or added on the way: the whole report compares equal,
    // and its JSON has exactly the struct's keys.
    let mut expected = report;
    expected.accuracy.rmse_state = None;
    assert_eq!(parsed, expected);
    assert_eq!(serde_json::to_value(&parsed).unwrap(), v);
}

#[test]
fn every_reason_list_names_every_variant_in_counter_order() {
    use crate::stage::{chain_guard, control, filter, ingest, plant, DropReason};
    use strum::VariantNames;
    fn names<T: Copy + Into<&'static str>>(all: &[T]) -> Vec<&'static str> {
        all.iter().map(|&r| r.into()).collect()
    }
    // VARIANTS is in declaration order, which is the counter index order
    // (the discriminants): an ALL list missing a variant fails here.
    assert_eq!(names(&ingest::Reason::ALL), ingest::Reason::VARIANTS);
    assert_eq!(names(&filter::Reason::ALL), filter::Reason::VARIANTS);
    assert_eq!(names(&control::Reason::ALL), control::Reason::VARIANTS);
    assert_eq!(names(&plant::Reason::ALL), plant::Reason::VARIANTS);
    assert_eq!(
        names(&chain_guard::Cause::ALL),
        chain_guard::Cause::VARIANTS
    );
    assert_eq!(names(&DropReason::ALL), DropReason::VARIANTS);
    for (i, r) in ingest::Reason::ALL.iter().enumerate() {
        assert_eq!(*r as usize, i);
    }
    for (i, r) in filter::Reason::ALL.iter().enumerate() {
        assert_eq!(*r as usize, i);
    }
    // The plant refuses what every actuator refuses, under the same names.
    use crate::ipc::ControlReject;
    assert_eq!(
        names(&[
            ControlReject::Dimension,
            ControlReject::NonFinite,
            ControlReject::Limit
        ]),
        &plant::Reason::VARIANTS[..3]
    );
    // Report keys: the documented names.
    assert_eq!(
        filter::Reason::VARIANTS,
        [
            "time_backwards",
            "dimension",
            "non_finite",
            "degenerate",
            "numerical",
            "snapshot",
            "time_out_of_range",
            "foreign_publisher"
        ]
    );
    assert_eq!(
        DropReason::VARIANTS,
        ["lost", "stale", "superseded", "shutdown"]
    );
}

/// The filter stage's stats of a PF run in which 7 of 400 updates collapsed.
fn with_collapsing_filter(inp: &mut ReportInput, counted: bool) {
    let (_, end) = inp
        .stages
        .iter_mut()
        .find(|(k, _)| *k == StageKind::Filter)
        .unwrap();
    end.stats = Some(StageStats {
        stage: StageKind::Filter as u32,
        processed: 400,
        ess_collapses: 7,
        flags: if counted {
            crate::ipc::stats_flags::COLLAPSES_COUNTED
        } else {
            0
        },
        ..StageStats::default()
    });
}

#[test]
fn collapsed_filter_steps_are_in_the_json_its_round_trip_and_the_tables() {
    let mut inp = input();
    // No filter stats: null collapses, no line.
    let v = inp.to_json();
    assert!(v["filter"]["ess_collapses"].is_null());
    assert_eq!(v["filter"]["updates"], json!(0));
    assert!(!inp.render().contains("collapsed"));
    with_collapsing_filter(&mut inp, true);
    let report = inp.report();
    assert_eq!(report.filter.ess_collapses, Some(7));
    assert_eq!(report.filter.updates, 400);
    let text = serde_json::to_string(&inp.to_json()).unwrap();
    let parsed: RunReport = serde_json::from_str(&text).unwrap();
    assert_eq!(parsed.schema_version, REPORT_SCHEMA_VERSION);
    assert_eq!(parsed, report);
    assert!(
        inp.render().contains("filter: 7 of 400 updates collapsed"),
        "{}",
        inp.render()
    );
    // A Gaussian filter (flag not set) has no collapses to report.
    with_collapsing_filter(&mut inp, false);
    assert_eq!(inp.report().filter.ess_collapses, None);
    assert!(!inp.render().contains("collapsed"));
}

/// Additive: a report written before the `filter` section parses, with
/// the section's defaults (so the schema version stays).
#[test]
fn a_report_without_the_filter_section_still_parses() {
    let mut v = input().to_json();
    v.as_object_mut().unwrap().remove("filter");
    let parsed: RunReport = serde_json::from_value(v).unwrap();
    assert_eq!(parsed.filter, FilterReport::default());
}

#[test]
fn the_scenarios_own_figures_are_printed_on_one_line() {
    let mut inp = input();
    inp.accuracy.scenario = None;
    assert!(!inp.render().contains("\nship:"));
    inp.accuracy.scenario = Some(serde_json::json!({
        "tracking_mse": 1.5,
        "detected": 3,
        "detection_delays": [{"step": 10, "delay": 2}, {"step": 90, "delay": 4}],
    }));
    let t = inp.render();
    assert!(
        t.contains("ship: detected 3, detection_delays [2 entries], tracking_mse 1.5000\n"),
        "{t}"
    );
}

/// The control stage of [`input`] with three misses listed, 41 more pushed
/// out of its log; the run started at 5 s on CLOCK_MONOTONIC.
fn input_with_misses() -> ReportInput {
    use crate::ipc::MissStats;
    let mut inp = input();
    let (_, end) = inp
        .stages
        .iter_mut()
        .find(|(k, _)| *k == StageKind::Control)
        .unwrap();
    let ctl = end.stats.as_mut().unwrap();
    ctl.deadline_misses = 44;
    // 39 of them in the first 1.5 s of the stage, 5 after.
    ctl.deadline_misses_warmup = 39;
    ctl.miss_warmup_ns = 1_500_000_000;
    ctl.miss_log_overwritten = 41;
    let slot =
        |start_ns, wall_ns, cpu_ns, switches, kind, (minor_faults, major_faults)| MissStats {
            start_ns,
            wall_ns,
            cpu_ns,
            switches,
            kind,
            reserved: 0,
            minor_faults,
            major_faults,
        };
    // 12.345 678 901 s after the start: an overrun, no switch, 1 fault.
    ctl.miss_log[0] = slot(17_345_678_901, 115_800, 116_400, 0, 1, (1, 0));
    // Preempted, one switch, 240 minor and 3 major faults; host, CPU
    // time, switches and faults unknown.
    ctl.miss_log[1] = slot(17_400_000_000, 1_087_000, 544_000, 1, 2, (240, 3));
    let unknown = crate::ipc::MISS_UNKNOWN;
    ctl.miss_log[2] = slot(
        20_000_002_000,
        4_331_000,
        unknown,
        unknown,
        3,
        (unknown, unknown),
    );
    inp
}

#[test]
fn a_stages_misses_are_listed_with_their_times_in_json_and_text() {
    let inp = input_with_misses();
    let v = inp.to_json();
    assert_eq!(v["run_start_ns"], json!(5_000_000_000u64));
    let c = &v["stages"]["control"];
    assert_eq!(c["misses_not_listed"], json!(41));
    let m = c["misses"].as_array().unwrap();
    assert_eq!(m.len(), 3);
    assert_eq!(
        m[0],
        json!({"t_us": 12_345_678.901, "t_ns": 17_345_678_901u64, "wall_us": 115.8,
               "cpu_us": 116.4, "switches": 0, "minor_faults": 1, "major_faults": 0,
               "kind": "overrun"})
    );
    assert_eq!(m[1]["t_us"], json!(12_400_000.0));
    assert_eq!(
        (m[1]["switches"].clone(), m[1]["kind"].clone()),
        (json!(1), json!("preempted"))
    );
    assert_eq!(
        (m[1]["minor_faults"].clone(), m[1]["major_faults"].clone()),
        (json!(240), json!(3))
    );
    assert_eq!(
        m[2],
        json!({"t_us": 15_000_002.0, "t_ns": 20_000_002_000u64, "wall_us": 4331.0,
               "cpu_us": null, "switches": null, "minor_faults": null,
               "major_faults": null, "kind": "host"})
    );
    // Warm-up and after add up to the total.
    assert_eq!(c["deadline_misses_warmup"], json!(39));
    assert_eq!(c["deadline_misses_after_warmup"], json!(5));
    assert_eq!(c["miss_warmup_s"], json!(1.5));
    // Listed + not listed = every miss; the other stages have none.
    assert_eq!(m.len() as u64 + 41, c["deadline_misses"].as_u64().unwrap());
    assert_eq!(v["stages"]["filter"]["misses"], json!([]));
    assert_eq!(v["stages"]["filter"]["misses_not_listed"], json!(0));
    // The report round-trips through its serde structs.
    let back: RunReport = serde_json::from_value(v.clone()).unwrap();
    assert_eq!(back.stages["control"].misses[0].t_ns, 17_345_678_901);

    let text = inp.render();
    let lines: Vec<&str> = text.lines().filter(|l| l.contains("control")).collect();
    let want = [
        "41 earlier control misses not listed (the list keeps the latest 32)",
        "control miss at t=12.345 678 s (mono 17.345678 s): 115.8 µs wall, 116.4 µs CPU, 0 switches, 1 fault (overrun)",
        "control miss at t=12.400 000 s (mono 17.400000 s): 1087.0 µs wall, 544.0 µs CPU, 1 switch, 243 faults (3 major) (preempted)",
        "control miss at t=15.000 002 s (mono 20.000002 s): 4331.0 µs wall, CPU time unknown, switches unknown, faults unknown (host)",
    ];
    for w in want {
        assert!(lines.contains(&w), "missing {w:?} in\n{text}");
    }
    // Under the stage table, before the summary, in order.
    let at = |s: &str| text.find(s).unwrap();
    assert!(at("stage ") < at(want[0]) && at(want[0]) < at(want[1]));
    assert!(at(want[1]) < at(want[2]) && at(want[2]) < at(want[3]));
    assert!(at(want[3]) < at("accuracy:"));
    // The stage table shows the total, the warm-up's and the rest.
    let row: Vec<&str> = text
        .lines()
        .find(|l| l.starts_with("control "))
        .unwrap()
        .split_whitespace()
        .collect();
    assert_eq!(&row[6..9], ["44", "39", "5"], "{text}");
    assert!(text.contains("warm: misses that started in the first 1.5 s"));
    // A run without misses prints no miss line.
    assert!(!input().render().contains(" miss at "));
    assert!(!input().render().contains("warm: "));
}
