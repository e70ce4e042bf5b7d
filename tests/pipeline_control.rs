//! The default pipeline steers the ship with the implicit-sampling
//! path-integral controller: `beliefbus run` with no config runs
//! `configs/default.toml`, whose controller must be `implicit` and must
//! reach waypoints of the route, with the report's control section filled.
//! MPPI stays selectable with `--set control.backend=mppi`.

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};
use std::sync::Mutex;

mod scratch_support;
use scratch_support::Scratch;

/// Pipelines pin themselves to the same cores: one at a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")))
        .output()
        .unwrap()
}

/// A scratch file, removed with its directory when the test ends.
fn tmp(name: &str) -> Scratch {
    Scratch::new("ctl-test", name)
}

fn run_report(name: &str, extra: &[&str]) -> Value {
    let report = tmp(name);
    let mut args = vec!["run", "--duration", "12", "--quiet"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--report", report.to_str().unwrap()]);
    let o = run(&args);
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    r
}

/// Route (5,5) → (−5,5) → … from (3,0) at rest; 12 s reach at least the
/// first waypoint (5.4 away; the uncontrolled ship, a random walk with
/// e = 0.3, almost never gets within the 1.0 radius in 12 s).
#[test]
fn the_default_run_is_steered_by_the_implicit_controller_through_waypoints() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let r = run_report("default.json", &[]);
    assert_eq!(r["controller"], "implicit");
    let c = &r["control"];
    assert_eq!(c["controller"], "implicit", "{c}");
    let reached = c["waypoints_reached"].as_u64().unwrap();
    assert!(reached >= 1, "no waypoint reached: {c}");
    assert!(c["controls_received"].as_u64().unwrap() > 100, "{c}");
    // The cost and the compute percentiles are measured, not placeholders.
    let cost = c["cost"].as_f64().expect("control.cost");
    assert!(cost.is_finite() && cost > 0.0, "{c}");
    let p50 = c["compute_p50_us"].as_f64().expect("compute_p50_us");
    let p99 = c["compute_p99_us"].as_f64().expect("compute_p99_us");
    assert!(p50 > 0.0 && p99 >= p50, "{c}");
    // Every control succeeded (no fallback to the last good one).
    assert_eq!(
        r["stages"]["control"]["rejected"], 0,
        "{}",
        r["stages"]["control"]
    );
}

#[test]
fn mppi_remains_selectable() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let r = run_report("mppi.json", &["--set", "control.backend=mppi"]);
    assert_eq!(r["controller"], "mppi");
    assert_eq!(r["control"]["controller"], "mppi");
    assert!(r["control"]["waypoints_reached"].as_u64().unwrap() >= 1);
}
