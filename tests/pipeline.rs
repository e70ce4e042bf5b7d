//! The real multi-process pipeline, end to end: `beliefbus run` spawns the
//! five stage executables under its own shared-memory prefix.
//!
//! Pipelines are run one at a time (they pin themselves to the same cores).

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

mod launcher_support;
mod scratch_support;
use launcher_support::{root, Run};
use scratch_support::Scratch;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_beliefbus")
}

/// A scratch file, removed with its directory when the test ends.
fn tmp(name: &str) -> Scratch {
    Scratch::new("test", name)
}

/// Every file under /dev/shm and iceoryx2's root path that starts with `prefix`.
fn shm_files(prefix: &str) -> Vec<PathBuf> {
    beliefbus::ipc::cleanup::resources(prefix)
}

fn run(args: &[&str]) -> Output {
    Command::new(exe())
        .args(args)
        .current_dir(root())
        .output()
        .unwrap()
}

/// `beliefbus ARGS` started outside the repository: built-in configs must
/// not depend on the working directory.
fn run_elsewhere(args: &[&str]) -> Output {
    let dir = tmp("cwd");
    Command::new(exe())
        .args(args)
        .current_dir(dir.dir())
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn read_report(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn check_report_keys(r: &Value) {
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
        assert!(r.get(k).is_some(), "report lacks {k}");
    }
    for h in [
        "sensor->ingest",
        "ingest->filter",
        "filter->control",
        "sensor->belief",
        "sensor->control",
    ] {
        for k in ["count", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"] {
            assert!(r["hops"][h].get(k).is_some(), "report lacks hops.{h}.{k}");
        }
    }
    for s in ["ingest", "filter", "control", "refine", "plant"] {
        for k in [
            "pid",
            "core",
            "processed",
            "dropped",
            "rejected",
            "deadline_misses",
            "compute_p50_us",
            "compute_p99_us",
            "budget_us",
        ] {
            assert!(
                r["stages"][s].get(k).is_some(),
                "report lacks stages.{s}.{k}"
            );
        }
    }
    for k in ["rmse_position", "rmse_state", "rmse_position_raw"] {
        assert!(r["accuracy"].get(k).is_some(), "report lacks accuracy.{k}");
    }
    for k in ["waypoints_reached", "mean_distance_to_waypoint"] {
        assert!(r["control"].get(k).is_some(), "report lacks control.{k}");
    }
}

#[test]
fn the_closed_loop_runs_across_five_processes_and_leaves_nothing_behind() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("closed-loop.json");
    // No config: the default scenario's built-in config, from outside the
    // repository.
    let o = run_elsewhere(&[
        "run",
        "--duration",
        "4",
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "exit {:?}: {}", o.status, stderr(&o));
    let r = read_report(&report);
    check_report_keys(&r);
    let prefix = r["prefix"].as_str().unwrap();
    assert!(prefix.starts_with("iox2_bb-"));
    assert!(
        shm_files(prefix).is_empty(),
        "left: {:?}",
        shm_files(prefix)
    );
    assert_eq!(r["shared_memory"]["files_left"], 0);

    // Five distinct processes, each of which processed data and stopped cleanly.
    let mut pids = std::collections::HashSet::new();
    for s in ["ingest", "filter", "control", "refine", "plant"] {
        let st = &r["stages"][s];
        pids.insert(st["pid"].as_u64().unwrap());
        let processed = st["processed"].as_u64().unwrap();
        if s == "refine" {
            // The background stage (nice 19) may be starved on a busy
            // machine: it must have worked, and accounted for every
            // belief it did not follow.
            let dropped = st["dropped"].as_u64().unwrap();
            assert!(processed > 0 && processed + dropped > 100, "{s}: {st}");
        } else {
            assert!(processed > 100, "{s}: {st}");
        }
        assert_eq!(st["exit_status"], "exit 0", "{s}");
        assert_eq!(st["final_report"], true, "{s}");
    }
    assert_eq!(pids.len(), 5);
    assert!(!pids.contains(&(std::process::id() as u64)));
    // Controls reached the plant, and the hops saw them.
    assert!(r["control"]["controls_received"].as_u64().unwrap() > 100);
    assert!(r["hops"]["sensor->control"]["count"].as_u64().unwrap() > 100);
    // The filter beats inverting each measurement.
    let acc = &r["accuracy"];
    assert!(acc["rmse_position"].as_f64().unwrap() < acc["rmse_position_raw"].as_f64().unwrap());
    assert_eq!(r["stages"]["ingest"]["rejected"], 0);
    // Every observation ingest published was counted by the filter
    // (processed, dropped by reason or rejected); the plant stops first, so
    // at most what ingest still held can have been in flight at the stop.
    let obs = &r["streams"]["observations"];
    let unaccounted = obs["unaccounted"].as_i64().unwrap();
    assert_eq!(
        obs["published"].as_i64().unwrap(),
        obs["counted"].as_i64().unwrap() + unaccounted,
        "{obs}"
    );
    assert!((0..=16).contains(&unaccounted), "{obs}");
    // Every stage's drops carry a reason (refine's superseded and lost
    // beliefs, the plant's skipped ticks included).
    for s in ["ingest", "filter", "control", "refine", "plant"] {
        let st = &r["stages"][s];
        let by: u64 = st["dropped_by_reason"]
            .as_object()
            .unwrap_or_else(|| panic!("stages.{s}.dropped_by_reason: {st}"))
            .values()
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(by, st["dropped"].as_u64().unwrap(), "stages.{s}: {st}");
    }
    // The status lines and the tables were printed.
    assert!(stderr(&o).contains("sensor->control p50"), "{}", stderr(&o));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("sensor->control") && table.contains("refine"));
}

#[test]
fn estimation_only_runs_with_the_ekf_and_no_control_output() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("vdp.json");
    let o = run_elsewhere(&[
        "run",
        "--scenario",
        "vanderpol",
        "--duration",
        "3",
        "--quiet",
        "--set",
        "filter.backend=ekf",
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "exit {:?}: {}", o.status, stderr(&o));
    let r = read_report(&report);
    check_report_keys(&r);
    assert_eq!(r["filter_backend"], "ekf");
    assert_eq!(r["controller"], "none");
    assert!(r["hops"]["sensor->belief"]["count"].as_u64().unwrap() > 50);
    assert_eq!(r["hops"]["sensor->control"]["count"], 0);
    assert!(r["stages"]["control"]["processed"].as_u64().unwrap() > 50);
    let acc = &r["accuracy"];
    assert!(acc["rmse_position"].as_f64().unwrap() < acc["rmse_position_raw"].as_f64().unwrap());
    assert!(shm_files(r["prefix"].as_str().unwrap()).is_empty());
}

#[test]
fn scenarios_lists_the_registry_with_each_ones_backends() {
    let o = run_elsewhere(&["scenarios"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("ship (default):"), "{out}");
    assert!(out.contains("vanderpol:"), "{out}");
    assert!(
        out.contains(
            "filter.backend: chain | pf | ekf | ukf | projection-pf; control.backend: implicit | mppi | none"
        ),
        "{out}"
    );
    assert!(out.contains("control.backend: none\n"), "{out}");
    // A discrete-time scenario lists only the backends it brings.
    assert!(
        out.contains("filter.backend: rbpf-changepoint; control.backend: arx-adaptive | none"),
        "{out}"
    );
    assert!(
        out.contains(
            "filter.backend: projection-pf; control.backend: belief-mdp | ce-threshold | none"
        ),
        "{out}"
    );
    // An unknown scenario is a config error naming the registered ones.
    let o = run_elsewhere(&["run", "--scenario", "warp", "--duration", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains(
            "registered: ship, vanderpol, arx, carpark, inventory, victoria-park, light-dark"
        ),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_bad_config_exits_2_with_one_line_naming_the_key() {
    // Unknown key and wrong type through --set ...
    for (set, key) in [
        ("filter.pf.particlez=10", "filter.pf.particlez"),
        ("filter.pf.particles=\"many\"", "filter.pf.particles"),
        ("stages.filter.core=99", "stages.filter.core"),
    ] {
        let o = run(&["run", "--duration", "1", "--set", set]);
        assert_eq!(o.status.code(), Some(2), "{set}: {}", stderr(&o));
        let e = stderr(&o);
        assert_eq!(e.trim_end().lines().count(), 1, "{set}: {e}");
        assert!(e.contains(key), "{set}: {e}");
    }
    // ... and in a file.
    let text = std::fs::read_to_string(root().join("configs/default.toml")).unwrap();
    let bad = tmp("bad.toml");
    std::fs::write(
        &bad,
        text.replace("[plant]\n", "[plant]\nsensor_rte_hz = 5\n"),
    )
    .unwrap();
    let o = run(&["run", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o).trim_end().lines().count(), 1, "{}", stderr(&o));
    assert!(stderr(&o).contains("plant.sensor_rte_hz"), "{}", stderr(&o));
    std::fs::write(
        &bad,
        text.replace("sensor_rate_hz = 100.0", "sensor_rate_hz = \"fast\""),
    )
    .unwrap();
    let o = run(&["run", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("plant.sensor_rate_hz"),
        "{}",
        stderr(&o)
    );
    // A stage executable rejects the same config the same way.
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus-filter"))
        .arg(bad.to_str().unwrap())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o).trim_end().lines().count(), 1, "{}", stderr(&o));
}

#[test]
fn ctrl_c_stops_the_run_cleanly() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("sigint.json");
    let mut child = Command::new(exe())
        .args([
            "run",
            "--duration",
            "0",
            "--report",
            report.to_str().unwrap(),
        ])
        .current_dir(root())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for the first status lines, then interrupt.
    let mut err = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut err, &mut s).unwrap();
        s
    });
    std::thread::sleep(Duration::from_secs(3));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            Instant::now() < deadline,
            "launcher did not stop after SIGINT"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let err = reader.join().unwrap();
    assert!(status.success(), "{status:?}: {err}");
    assert!(err.contains("stopping (signal)"), "{err}");
    let r = read_report(&report);
    check_report_keys(&r);
    for s in ["ingest", "filter", "control", "refine", "plant"] {
        assert_eq!(r["stages"][s]["exit_status"], "exit 0", "{s}");
        let pid = r["stages"][s]["pid"].as_u64().unwrap() as i32;
        // SAFETY: probing a pid.
        assert_ne!(unsafe { libc::kill(pid, 0) }, 0, "{s} still alive");
    }
    assert!(shm_files(r["prefix"].as_str().unwrap()).is_empty());
}

#[test]
fn a_crashed_stage_leaves_nothing_after_cleanup() {
    // A stage started by hand under its own prefix, then killed with
    // SIGKILL: its files stay until the prefix is cleaned, then none remain.
    let prefix = beliefbus::ipc::cleanup::run_prefix();
    let mut child = Command::new(env!("CARGO_BIN_EXE_beliefbus-refine"))
        .args([
            "configs/default.toml",
            "--prefix",
            &prefix,
            "--set",
            "stages.refine.nice=0",
        ])
        .current_dir(root())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while shm_files(&prefix).len() < 3 {
        assert!(Instant::now() < deadline, "refine did not come up");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !shm_files(&prefix).is_empty(),
        "a killed process leaves its files"
    );
    let r = beliefbus::ipc::cleanup::remove_prefix(&prefix).unwrap();
    assert_eq!(r.alive_nodes, 0);
    assert!(r.dead_nodes_removed >= 1, "{r:?}");
    assert!(
        shm_files(&prefix).is_empty(),
        "left: {:?}",
        shm_files(&prefix)
    );
}

#[test]
fn after_the_launcher_is_killed_its_stages_stop_and_a_sweep_removes_the_run() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut run = Run::start(&["run", "--duration", "0"]);
    let prefix = run.prefix();
    assert!(prefix.starts_with("iox2_bb-"), "{prefix}");
    // A status line: all up.
    run.expect("sensor->control p50");
    run.child.kill().unwrap(); // SIGKILL: no cleanup by the launcher
    run.child.wait().unwrap();
    // The stages get SIGTERM (parent-death signal), stop and drop their nodes.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (alive, _, _) = beliefbus::ipc::cleanup::remove_dead_nodes(&prefix).unwrap();
        if alive == 0 {
            break;
        }
        assert!(Instant::now() < deadline, "stages outlived the launcher");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        !shm_files(&prefix).is_empty(),
        "the launcher's own files stay"
    );
    let swept = beliefbus::ipc::cleanup::sweep_stale_runs();
    assert!(swept.contains(&prefix), "{swept:?}");
    assert!(
        shm_files(&prefix).is_empty(),
        "left: {:?}",
        shm_files(&prefix)
    );
}

#[test]
fn stages_started_by_hand_form_a_pipeline_and_clean_up_after_themselves() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    use beliefbus::ipc::{Bus, Control, StageStats};
    let prefix = beliefbus::ipc::cleanup::run_prefix();
    let set_prefix = format!("run.prefix=\"{prefix}\"");
    let cfg = beliefbus::pipeline::config::load(
        &root().join("configs/default.toml"),
        std::slice::from_ref(&set_prefix),
    )
    .unwrap();
    let bus = Bus::open(&cfg.bus(), "observer").unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let controls = bus.subscriber_with::<Control>(256, false).unwrap();
    let start = |name: &str| {
        Command::new(match name {
            "ingest" => env!("CARGO_BIN_EXE_beliefbus-ingest"),
            "filter" => env!("CARGO_BIN_EXE_beliefbus-filter"),
            "control" => env!("CARGO_BIN_EXE_beliefbus-control"),
            "refine" => env!("CARGO_BIN_EXE_beliefbus-refine"),
            _ => env!("CARGO_BIN_EXE_beliefbus-plant"),
        })
        .args(["configs/default.toml", "--set", &set_prefix])
        .current_dir(root())
        .spawn()
        .unwrap()
    };
    let mut children: Vec<_> = ["control", "refine", "filter", "ingest"]
        .iter()
        .map(|n| start(n))
        .collect();
    // Wait for their first reports, then start the plant.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut up = std::collections::HashSet::new();
    while up.len() < 4 {
        assert!(Instant::now() < deadline, "stages did not come up");
        while let Some(s) = stats.receive().unwrap() {
            up.insert(s.stage);
        }
        controls.refresh();
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(200));
    children.push(start("plant"));
    let mut n = 0;
    let deadline = Instant::now() + Duration::from_secs(30);
    while n < 100 {
        assert!(Instant::now() < deadline, "only {n} controls");
        while controls.receive().unwrap().is_some() {
            n += 1;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(controls);
    drop(stats);
    drop(bus);
    for c in &children {
        // SAFETY: signalling our own children.
        unsafe { libc::kill(c.id() as i32, libc::SIGINT) };
    }
    for c in &mut children {
        assert!(c.wait().unwrap().success());
    }
    // The last one out removed the prefix (our observer node left first).
    let deadline = Instant::now() + Duration::from_secs(10);
    while !shm_files(&prefix).is_empty() {
        if Instant::now() > deadline {
            let _ = beliefbus::ipc::cleanup::remove_prefix(&prefix);
            panic!("left behind: {:?}", shm_files(&prefix));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}
