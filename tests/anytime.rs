//! The anytime chain in the running pipeline (issue 4): the default scenario
//! filters on the refine stage's live chain snapshots, and losing refine
//! does not stop beliefs or controls.
//!
//! Pipelines are run one at a time (they pin themselves to the same cores).

use beliefbus::ipc::{cleanup, Belief, Bus, BusConfig, Control, StageKind, StageStats};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Removes the run's shared memory when dropped, also when an assertion
/// fails mid-test.
struct Teardown(String);

impl Drop for Teardown {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.0);
    }
}

/// Stages started by hand; those still running are killed when dropped.
struct Stages(Vec<(&'static str, Child)>);

impl Drop for Stages {
    fn drop(&mut self) {
        for (_, c) in &mut self.0 {
            if matches!(c.try_wait(), Ok(None)) {
                let _ = c.kill();
            }
            let _ = c.wait();
        }
    }
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("beliefbus-anytime-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn a_run_on_the_live_chain_swaps_versions_and_beats_raw_measurements() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("default.json");
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        // Estimation only (the closed loop on the chain filter is measured
        // in chain-closed-loop and by `run --set filter.backend=chain`), on
        // one incrementally grown chain: the moving frame needs a fresh
        // batch chain per version, which a CPU-starved refine (nice 19, a
        // loaded test machine: 3 versions in 8 s) does not deliver — open
        // work in issue 4.
        .args(["run", "--duration", "8", "--quiet"])
        .args(["--set", "filter.backend=\"chain\""])
        .args(["--set", "control.backend=\"none\""])
        .args(["--set", "refine.moving_frame=false"])
        .arg("--report")
        .arg(&report)
        .current_dir(root())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["filter_backend"], "chain");
    let c = &r["chain"];
    // A new version every 200 ms: many swaps in 8 s, each remapping the
    // belief by state id.
    assert!(c["versions"].as_u64().unwrap() > 10, "{c}");
    assert!(
        c["published"].as_u64().unwrap() >= c["versions"].as_u64().unwrap(),
        "{c}"
    );
    let states = c["states"].as_u64().unwrap();
    assert!(
        (100..=4000).contains(&states),
        "bounded by refine.max_states: {c}"
    );
    assert!(c["delta_s"].as_f64().unwrap() > 0.0 && c["delta_s"].as_f64().unwrap() <= 0.01);
    assert!(c["swap_p99_us"].as_f64().unwrap() >= c["swap_p50_us"].as_f64().unwrap());
    let lost = c["mass_lost_max"].as_f64().unwrap();
    assert!((0.0..=1.0 + 1e-9).contains(&lost), "{c}");
    assert_eq!(r["stages"]["filter"]["rejected_by_reason"]["snapshot"], 0);
    let acc = &r["accuracy"];
    assert!(
        acc["rmse_position"].as_f64().unwrap() < acc["rmse_position_raw"].as_f64().unwrap(),
        "{acc}"
    );
    let prefix = r["prefix"].as_str().unwrap();
    assert!(cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
}

fn spawn(kind: &str, prefix: &str) -> Child {
    let exe = match kind {
        "ingest" => env!("CARGO_BIN_EXE_beliefbus-ingest"),
        "filter" => env!("CARGO_BIN_EXE_beliefbus-filter"),
        "control" => env!("CARGO_BIN_EXE_beliefbus-control"),
        "refine" => env!("CARGO_BIN_EXE_beliefbus-refine"),
        _ => env!("CARGO_BIN_EXE_beliefbus-plant"),
    };
    Command::new(exe)
        .args(["configs/default.toml", "--prefix", prefix])
        .args(["--set", "filter.backend=\"chain\""])
        .current_dir(root())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Beliefs and controls received, and the filter's latest stats, over `d`.
fn watch(
    beliefs: &beliefbus::ipc::Subscriber<Belief>,
    controls: &beliefbus::ipc::Subscriber<Control>,
    stats: &beliefbus::ipc::Subscriber<StageStats>,
    filter: &mut Option<StageStats>,
    d: Duration,
) -> (u64, u64) {
    let (mut nb, mut nc) = (0, 0);
    let end = Instant::now() + d;
    while Instant::now() < end {
        while beliefs.receive().unwrap().is_some() {
            nb += 1;
        }
        while controls.receive().unwrap().is_some() {
            nc += 1;
        }
        while let Some(s) = stats.receive().unwrap() {
            if s.stage == StageKind::Filter as u32 {
                *filter = Some(s);
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    (nb, nc)
}

#[test]
fn killing_refine_mid_run_does_not_stop_beliefs_or_controls() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = cleanup::run_prefix();
    let _teardown = Teardown(prefix.clone());
    let bus_cfg = BusConfig {
        prefix: prefix.clone(),
        instance: "ship".into(),
    };
    {
        let bus = Bus::open(&bus_cfg, "test").unwrap();
        let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
        let controls = bus.subscriber_with::<Control>(256, false).unwrap();
        let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
        let mut children = Stages(
            ["control", "refine", "filter", "ingest"]
                .into_iter()
                .map(|k| (k, spawn(k, &prefix)))
                .collect(),
        );
        std::thread::sleep(Duration::from_millis(500));
        children.0.push(("plant", spawn("plant", &prefix)));
        // Until the filter runs on the live chain.
        let mut filter = None;
        let t0 = Instant::now();
        while filter.is_none_or(|f: StageStats| f.chain_versions < 3) {
            assert!(t0.elapsed() < Duration::from_secs(30), "no chain installed");
            watch(
                &beliefs,
                &controls,
                &stats,
                &mut filter,
                Duration::from_millis(100),
            );
        }
        // The same two-second count with refine alive: the reference the
        // counts after the kill are held to (the controller's rate depends
        // on the machine and the build, not on refine).
        let (nb0, nc0) = watch(
            &beliefs,
            &controls,
            &stats,
            &mut filter,
            Duration::from_secs(2),
        );
        let before = filter.unwrap();
        let refine = children.0.iter_mut().find(|(k, _)| *k == "refine").unwrap();
        refine.1.kill().unwrap(); // SIGKILL
        refine.1.wait().unwrap();
        // Let the dead publisher go, then count for two seconds.
        watch(
            &beliefs,
            &controls,
            &stats,
            &mut filter,
            Duration::from_millis(500),
        );
        let (nb, nc) = watch(
            &beliefs,
            &controls,
            &stats,
            &mut filter,
            Duration::from_secs(2),
        );
        let after = filter.unwrap();
        // 100 Hz sensor: about 200 beliefs in two seconds; controls keep
        // flowing at (at least half) the rate they had before the kill.
        assert!(nb > 100, "beliefs after the kill: {nb} (before: {nb0})");
        assert!(
            nc > 0 && 2 * nc >= nc0,
            "controls after the kill: {nc}, before: {nc0}"
        );
        assert!(after.processed > before.processed + 100);
        // Still on the chain (the last snapshot stays mapped while held).
        assert!(after.chain_states > 0 && after.chain_versions >= before.chain_versions);
        for (k, c) in children.0.iter_mut().filter(|(k, _)| *k != "refine") {
            // SAFETY: signalling a child we spawned and have not reaped.
            unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
            let st = c.wait().unwrap();
            assert!(st.success(), "{k}: {st:?}");
        }
    }
    cleanup::remove_prefix(&prefix).unwrap();
    assert!(
        cleanup::resources(&prefix).is_empty(),
        "{:?}",
        cleanup::resources(&prefix)
    );
}
