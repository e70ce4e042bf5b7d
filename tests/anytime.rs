//! The anytime chain in the running pipeline: the default scenario
//! filters on the refine stage's live chain snapshots, and losing refine
//! (killed, or stopped) does not stop beliefs or controls: the stale-chain
//! fallback (`stage::chain_guard`) takes over and the estimate holds.
//!
//! Pipelines are run one at a time (they pin themselves to the same cores).

use beliefbus::ipc::{
    belief_status, cleanup, Belief, Bus, BusConfig, Control, StageKind, StageStats, Subscriber,
};
use serde_json::Value;
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

mod launcher_support;
mod scratch_support;
use launcher_support::{pid_of, root, Run, PATIENCE};
use scratch_support::Scratch;

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

/// A scratch file, removed with its directory when the test ends.
fn tmp(name: &str) -> Scratch {
    Scratch::new("anytime", name)
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
        // loaded test machine: 3 versions in 8 s) does not deliver.
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

/// A test's view of a run's bus: the beliefs and controls it counts and
/// the filter's latest stats report.
struct Watcher {
    beliefs: Subscriber<Belief>,
    controls: Subscriber<Control>,
    stats: Subscriber<StageStats>,
    /// The filter's latest stats report, if one came.
    filter: Option<StageStats>,
    _bus: Bus,
}

impl Watcher {
    /// Subscribe as node `name` to the run under `prefix`.
    fn open(prefix: &str, name: &str) -> Self {
        let bus = Bus::open(
            &BusConfig {
                prefix: prefix.to_string(),
                instance: "ship".into(),
            },
            name,
        )
        .unwrap();
        Self {
            beliefs: bus.subscriber_with::<Belief>(256, false).unwrap(),
            controls: bus.subscriber_with::<Control>(256, false).unwrap(),
            stats: bus.subscriber_with::<StageStats>(64, false).unwrap(),
            filter: None,
            _bus: bus,
        }
    }

    /// Beliefs and controls received over `d`.
    fn count(&mut self, d: Duration) -> (u64, u64) {
        let (nb, nc, _) = self.count_flagged(d);
        (nb, nc)
    }

    /// Keep watching until the filter's latest stats report satisfies
    /// `done` (it reports once per run.stats_period_s, so what was just
    /// counted shows up in a later report); `what` names the wait in the
    /// failure message.
    fn until(&mut self, what: &str, done: impl Fn(&StageStats) -> bool) {
        let t0 = Instant::now();
        while !self.filter.as_ref().is_some_and(&done) {
            assert!(
                t0.elapsed() < PATIENCE,
                "{what}: last report {:?}",
                self.filter
            );
            self.count(Duration::from_millis(100));
        }
    }

    /// [`Self::count`], also counting the beliefs that came from the
    /// stale-chain fallback (flagged `CHAIN_FALLBACK`).
    fn count_flagged(&mut self, d: Duration) -> (u64, u64, u64) {
        let (mut nb, mut nc, mut nf) = (0, 0, 0);
        let end = Instant::now() + d;
        while Instant::now() < end {
            while let Some(b) = self.beliefs.receive().unwrap() {
                nb += 1;
                if b.status & belief_status::CHAIN_FALLBACK != 0 {
                    nf += 1;
                }
            }
            while self.controls.receive().unwrap().is_some() {
                nc += 1;
            }
            while let Some(s) = self.stats.receive().unwrap() {
                if s.stage == StageKind::Filter as u32 {
                    self.filter = Some(s);
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        (nb, nc, nf)
    }
}

#[test]
fn killing_refine_mid_run_does_not_stop_beliefs_or_controls() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = cleanup::run_prefix();
    let _teardown = Teardown(prefix.clone());
    {
        let mut w = Watcher::open(&prefix, "test");
        let mut children = Stages(
            ["control", "refine", "filter", "ingest"]
                .into_iter()
                .map(|k| (k, spawn(k, &prefix)))
                .collect(),
        );
        std::thread::sleep(Duration::from_millis(500));
        children.0.push(("plant", spawn("plant", &prefix)));
        // Until the filter runs on the live chain.
        w.until("no chain installed", |f| f.chain_versions >= 3);
        // The same two-second count with refine alive: the reference the
        // counts after the kill are held to (the controller's rate depends
        // on the machine and the build, not on refine).
        let (nb0, nc0) = w.count(Duration::from_secs(2));
        let before = w.filter.unwrap();
        let refine = children.0.iter_mut().find(|(k, _)| *k == "refine").unwrap();
        refine.1.kill().unwrap(); // SIGKILL
        refine.1.wait().unwrap();
        // Let the dead publisher go and its last version go stale
        // (filter.chain.stale.max_age_ms, 1 s), then count for two seconds.
        w.count(Duration::from_millis(1200));
        let (nb, nc, nf) = w.count_flagged(Duration::from_secs(2));
        // The filter reports once per run.stats_period_s (the chain stays
        // stale meanwhile).
        w.until("fallback steps not counted", |f| {
            f.chain_fallback_steps >= before.chain_fallback_steps + nf
        });
        let after = w.filter.unwrap();
        // 100 Hz sensor: about 200 beliefs in two seconds; controls keep
        // flowing at (at least half) the rate they had before the kill.
        assert!(nb > 100, "beliefs after the kill: {nb} (before: {nb0})");
        assert!(
            nc > 0 && 2 * nc >= nc0,
            "controls after the kill: {nc}, before: {nc0}"
        );
        assert!(after.processed > before.processed + 100);
        // Still on the chain (the last snapshot stays mapped while held),
        // and the moving frame's last version is stale one second after
        // the kill: from then on the fallback's beliefs go out, flagged
        // and counted (an age episode, unless the chain went stale sooner).
        assert!(after.chain_states > 0 && after.chain_versions >= before.chain_versions);
        assert!(nf > 100, "fallback beliefs after the kill: {nf} of {nb}");
        assert!(after.chain_fallback_episodes.iter().sum::<u64>() >= 1);
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

/// The default scenario (moving-frame chain, closed loop) with refine
/// SIGSTOPped mid-run — a refine that gets no CPU at all, until the
/// supervisor kills it for its missed heartbeat and restarts it: beliefs
/// and controls keep flowing, the fallback's beliefs go out while the
/// chain is stale (counted as an age episode), a version after the
/// restart re-initialises the chain from the fallback, and the run's
/// position error stays below the raw measurements'.
#[test]
fn a_stopped_refine_hands_the_belief_to_the_fallback_and_the_estimate_holds() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("stopped-refine.json");
    let mut run = Run::start(&[
        "run",
        "--duration",
        "0",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
    ]);
    let prefix = run.prefix();
    let _teardown = Teardown(prefix.clone());
    run.expect("supervisor: started plant ");
    let stopped;
    {
        let mut w = Watcher::open(&prefix, "watcher");
        w.until("no chain installed", |f| f.chain_versions >= 3);
        let (_, nc0) = w.count(Duration::from_secs(2));
        let before = w.filter.unwrap();
        run.catch_up();
        stopped = run
            .log
            .iter()
            .rev()
            .find(|l| l.contains("started refine ") || l.contains("restarted refine "))
            .map(|l| pid_of(l))
            .unwrap();
        // SAFETY: signalling a stage process of our launcher.
        assert_eq!(unsafe { libc::kill(stopped, libc::SIGSTOP) }, 0);
        // The last version goes stale after filter.chain.stale.max_age_ms
        // (1 s); count the three seconds after that.
        w.count(Duration::from_millis(1200));
        let (nb, nc, nf) = w.count_flagged(Duration::from_secs(3));
        w.until("fallback steps not counted", |f| {
            f.chain_fallback_steps >= before.chain_fallback_steps + nf
        });
        let during = w.filter.unwrap();
        assert!(nb > 150, "beliefs with refine stopped: {nb}");
        assert!(
            nf * 10 >= nb * 9,
            "fallback beliefs with refine stopped: {nf} of {nb}"
        );
        assert!(
            nc > 0 && 2 * nc >= nc0,
            "controls with refine stopped: {nc}, before: {nc0}"
        );
        assert!(during.chain_fallback_episodes[1] > before.chain_fallback_episodes[1]);
        // Let it go (the supervisor may already have killed and restarted
        // it for its missed heartbeat): a new version ends the episode and
        // re-initialises the chain from the fallback's belief.
        // SAFETY: as above; a dead pid only fails.
        unsafe { libc::kill(stopped, libc::SIGCONT) };
        w.until("no re-initialisation after refine came back", |f| {
            f.chain_fallback_reinits > during.chain_fallback_reinits
        });
        // A few seconds more on the chain before the end.
        w.count(Duration::from_secs(3));
    }
    let st = run.interrupt();
    assert!(st.success(), "{st:?}:\n{}", run.log.join("\n"));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["filter_backend"], "chain");
    let c = &r["chain"];
    assert!(c["fallback_by_cause"]["age"].as_u64().unwrap() >= 1, "{c}");
    assert!(c["fallback_reinits"].as_u64().unwrap() >= 1, "{c}");
    assert!(c["fallback_steps"].as_u64().unwrap() >= 250, "{c}");
    assert!(c["stale_max_ms"].as_f64().unwrap() > 3000.0, "{c}");
    let acc = &r["accuracy"];
    assert!(
        acc["rmse_position"].as_f64().unwrap() < acc["rmse_position_raw"].as_f64().unwrap(),
        "{acc}"
    );
    assert!(r["control"]["controls_received"].as_u64().unwrap() > 0);
    assert_eq!(r["shared_memory"]["files_left"], 0);
    assert!(cleanup::resources(&prefix).is_empty());
}
