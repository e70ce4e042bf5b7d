//! The live car-park scenario through the whole multi-process pipeline, as
//! `beliefbus run --scenario carpark` starts it from any directory: the
//! multi-rate plant publishing odometry (40 Hz) and laser scans (≈ 4.7 Hz,
//! with gaps) on two channels, ingest merging them, and the scenario's
//! own MCL filters (a 12 s version of the 20 s acceptance run).
//!
//! The data set is drawn from a fixed seed, so dead reckoning's error is
//! the same every run (2.0 m RMS over these 11 counted seconds); the
//! filter, started 0.3 m / 0.02 rad off, must beat it with the laser.
//! Needs the Victoria Park folder; without it the test says so and passes
//! nothing else.

use serde_json::Value;
use std::process::Command;

fn run(backend: &str, controller: &str) -> Option<Value> {
    let data = beliefbus_localization::victoria::resolve_dir(None);
    // The run starts in a scratch directory: pass the folder absolute.
    let data = std::fs::canonicalize(&data).unwrap_or(data);
    if !data.join("odometry.csv").exists() {
        eprintln!(
            "skipped: no Victoria Park data at {} (set {})",
            data.display(),
            beliefbus_localization::victoria::DATA_ENV
        );
        return None;
    }
    let dir = std::env::temp_dir().join(format!(
        "beliefbus-carpark-{backend}-{controller}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let report = dir.join("carpark.json");
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args([
            "run",
            "--scenario",
            "carpark",
            "--duration",
            "12",
            "--quiet",
        ])
        .args([
            "--set",
            &format!("carpark.data_dir={:?}", data.display().to_string()),
        ])
        .args(["--set", &format!("filter.backend={backend:?}")])
        .args([
            "--set",
            &format!("control.backend={controller:?}"),
            "--report",
        ])
        .arg(&report)
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    Some(r)
}

/// What every run must show; `vs_dead_reckoning`: the replayed data set,
/// whose dead reckoning drifts by 2 m (a self-driving plant draws its own
/// path noise from the run seed, and its dead reckoning may not drift).
fn check(r: &Value, backend: &str, vs_dead_reckoning: bool) {
    assert_eq!(r["scenario"], "carpark");
    assert_eq!(r["filter_backend"], backend);
    for s in ["ingest", "filter", "plant"] {
        let st = &r["stages"][s];
        assert!(st["processed"].as_u64().unwrap() > 300, "{s}: {st}");
        assert_eq!(st["rejected"], 0, "{s}: {st}");
        assert_eq!(st["exit_status"], "exit 0", "{s}");
    }
    let m = &r["scenario_metrics"]["carpark"];
    let ch = &m["channels"];
    let n = |v: &Value| v.as_u64().unwrap();
    // 40 Hz over 12 s; scans at ~4.7 Hz less the gaps and empty scans.
    assert!(n(&ch["odometry"]["samples"]) >= 400, "{ch}");
    assert!(n(&ch["odometry"]["beliefs"]) >= 350, "{ch}");
    assert!(n(&ch["laser"]["samples"]) >= 20, "{ch}");
    assert!(n(&ch["laser"]["beliefs"]) >= 20, "{ch}");
    assert!(
        n(&ch["laser"]["features"]) >= n(&ch["laser"]["samples"]),
        "{ch}"
    );
    assert_eq!(n(&ch["other"]["samples"]), 0);
    // Laser steps happened, each timed, with an ESS in [1, M].
    let steps = n(&m["laser_steps"]);
    assert!(steps >= 20, "{m}");
    assert_eq!(n(&m["time_laser_step"]["n"]), steps);
    let f = |k: &str| m[k].as_f64().unwrap();
    assert!(
        f("ess_min") >= 1.0 - 1e-9 && f("ess_mean") <= 100.0 + 1e-9,
        "{m}"
    );
    let (pose, dr) = (
        f("pose_rmse_position_m"),
        f("dead_reckoning_rmse_position_m"),
    );
    assert!(pose < 1.5, "filter {pose} m: {m}");
    if vs_dead_reckoning {
        // The laser pulls the estimate below dead reckoning's error.
        assert!(dr > 1.0, "the stretch's dead reckoning drifts: {m}");
        assert!(pose < dr, "filter {pose} m vs dead reckoning {dr} m");
        let heading = f("pose_rmse_heading_rad");
        assert!(heading < f("dead_reckoning_rmse_heading_rad"), "{m}");
    }
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
}

#[test]
fn implicit_mcl_localizes_live_on_two_channels() {
    if let Some(r) = run("implicit-mcl", "none") {
        check(&r, "implicit-mcl", true);
    }
}

#[test]
fn standard_mcl_localizes_live_on_two_channels() {
    if let Some(r) = run("mcl", "none") {
        check(&r, "mcl", true);
    }
}

/// With `pure-pursuit` the vehicle drives itself on the filter's belief:
/// a control for (nearly) every odometry sample reaches the plant, and the
/// vehicle stays near the path the landmarks line.
#[test]
fn pure_pursuit_drives_the_car_on_implicit_mcl() {
    let Some(r) = run("implicit-mcl", "pure-pursuit") else {
        return;
    };
    check(&r, "implicit-mcl", false);
    assert_eq!(r["controller"], "pure-pursuit");
    let m = &r["scenario_metrics"]["carpark"];
    // (The acceptance run asks >= 95 %; a loaded CI machine gets slack.)
    let f = m["controlled_fraction"].as_f64().unwrap();
    assert!(f >= 0.9, "{m}");
    assert!(
        r["control"]["controls_received"].as_u64().unwrap() > 300,
        "{}",
        r["control"]
    );
    assert!(m["path_rmse_m"].as_f64().unwrap() < 2.0, "{m}");
}
