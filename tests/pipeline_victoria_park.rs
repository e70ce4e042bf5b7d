//! The real Victoria Park run through the whole multi-process pipeline, as
//! `beliefbus run configs/victoria-park.toml` starts it: the first 60 s of
//! the recording streamed at 20× (3 s live) on the odometry and
//! tree-feature channels into implicit SLAM, and the car park's SLAM
//! backend for 10 s. Needs the Victoria Park folder; without it the tests
//! say so and check nothing else.

use serde_json::Value;
use std::process::Command;

fn data() -> Option<std::path::PathBuf> {
    let data = beliefbus_localization::victoria::resolve_dir(None);
    let data = std::fs::canonicalize(&data).unwrap_or(data);
    if !data.join("derived/trees_detectTreesI16.csv").exists() {
        eprintln!(
            "skipped: no Victoria Park data at {} (set {})",
            data.display(),
            beliefbus_localization::victoria::DATA_ENV
        );
        return None;
    }
    Some(data)
}

fn run(scenario: &str, sets: &[String], duration: &str) -> Value {
    let dir = std::env::temp_dir().join(format!("beliefbus-{scenario}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let report = dir.join("report.json");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_beliefbus"));
    cmd.args([
        "run",
        "--scenario",
        scenario,
        "--duration",
        duration,
        "--quiet",
    ]);
    for s in sets {
        cmd.args(["--set", s]);
    }
    let o = cmd
        .arg("--report")
        .arg(&report)
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
    r
}

/// 60 s of the recording: both channels streamed and filtered, trees
/// mapped, and the estimate near GPS (dead reckoning is 2.4 m off at 60 s;
/// the start heading is a guess, so a few metres are normal).
#[test]
fn implicit_slam_maps_the_first_minute_of_victoria_park_live() {
    let Some(data) = data() else { return };
    let r = run(
        "victoria-park",
        &[
            format!("victoria-park.data_dir={:?}", data.display().to_string()),
            "victoria-park.speedup=20.0".into(),
            "victoria-park.end_time_s=82.0".into(),
            "victoria-park.filter.particles=50".into(),
        ],
        "4",
    );
    assert_eq!(r["scenario"], "victoria-park");
    assert_eq!(r["filter_backend"], "implicit-refine-slam");
    for s in ["ingest", "filter", "plant"] {
        let st = &r["stages"][s];
        assert_eq!(st["rejected"], 0, "{s}: {st}");
        assert_eq!(st["exit_status"], "exit 0", "{s}");
    }
    let m = &r["scenario_metrics"]["victoria-park"];
    let n = |v: &Value| v.as_u64().unwrap();
    // 60 s at 40 Hz: 2402 odometry samples; scans at ~4.7 Hz with trees.
    let ch = &m["channels"];
    assert_eq!(n(&ch["odometry"]["samples"]), n(&m["steps_in_run"]), "{m}");
    assert!(n(&ch["odometry"]["beliefs"]) > 2000, "{ch}");
    assert!(n(&ch["laser"]["samples"]) > 250, "{ch}");
    assert!(
        n(&ch["laser"]["detections"]) > n(&ch["laser"]["samples"]),
        "{ch}"
    );
    assert!(n(&m["steps_reached"]) + 50 >= n(&m["steps_in_run"]), "{m}");
    assert!(n(&m["gps_fixes_scored"]) > 100, "{m}");
    let f = |k: &str| m[k].as_f64().unwrap();
    let trees = f("map_landmarks");
    assert!((5.0..=150.0).contains(&trees), "{m}");
    assert!(f("gps_rms_m") < 10.0, "{m}");
    assert!(
        f("ess_min") >= 1.0 - 1e-9 && f("ess_mean") <= 50.0 + 1e-9,
        "{m}"
    );
}

/// SLAM on the car park: no map given, the filter builds one.
#[test]
fn implicit_slam_runs_live_on_the_car_park() {
    let Some(data) = data() else { return };
    let r = run(
        "carpark",
        &[
            format!("carpark.data_dir={:?}", data.display().to_string()),
            "filter.backend=\"implicit-slam\"".into(),
        ],
        "10",
    );
    assert_eq!(r["filter_backend"], "implicit-slam");
    let m = &r["scenario_metrics"]["carpark"];
    let f = |k: &str| m[k].as_f64().unwrap();
    assert!(m["laser_steps"].as_u64().unwrap() >= 15, "{m}");
    // The map holds about the landmarks the scans reported.
    let (map, seen) = (f("map_landmarks"), f("landmarks_seen"));
    assert!(map >= 0.5 * seen && map <= 2.0 * seen + 2.0, "{m}");
    assert!(f("pose_rmse_position_m") < 3.0, "{m}");
}
