//! Fault injection on the real multi-process pipeline: every stage
//! killed with SIGKILL in turn, one stopped with SIGSTOP beyond its
//! heartbeat deadline, a `--chaos` run, a stage whose policy forbids a
//! restart. Each time the supervisor must notice, clean up, restart and the
//! pipeline must deliver controls again; nothing may be left in /dev/shm.
//!
//! Recovery is asserted to happen (the supervisor's "recovered" line: the
//! restarted process reported and a control derived from a sensor sample
//! published after the death went out), never to take at most some time;
//! the generous waits below only keep a broken build from hanging CI.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

mod launcher_support;
mod scratch_support;
use launcher_support::{pid_of, root, Run, PATIENCE};
use scratch_support::Scratch;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// A scratch file, removed with its directory when the test ends.
fn tmp(name: &str) -> Scratch {
    Scratch::new("rel", name)
}

fn shm_files(prefix: &str) -> Vec<PathBuf> {
    beliefbus::ipc::cleanup::shm_files(prefix)
}

fn read_report(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn kill(pid: i32, sig: libc::c_int) {
    // SAFETY: signalling a stage process of our launcher.
    assert_eq!(unsafe { libc::kill(pid, sig) }, 0, "kill {pid}");
}

#[test]
fn every_stage_killed_in_turn_and_a_hung_filter_recover_and_leave_nothing_behind() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("kill-each.json");
    let mut run = Run::start(&[
        "run",
        "configs/default.toml",
        "--duration",
        "0",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
        // Faster heartbeats so the hang is noticed sooner (not required).
        "--set",
        "run.stats_period_s=0.2",
        "--set",
        "stages.filter.restart.heartbeat_timeout_ms=1000",
    ]);
    let prefix = run.prefix();
    let mut pids = std::collections::HashMap::new();
    for s in ["control", "refine", "filter", "ingest", "plant"] {
        let l = run.expect(&format!("supervisor: started {s} "));
        pids.insert(s, pid_of(&l));
    }
    // Let the loop settle, then count the run's shared-memory files.
    std::thread::sleep(Duration::from_secs(2));
    let before = shm_files(&prefix).len();
    assert!(before > 0);

    for s in ["filter", "ingest", "control", "refine", "plant"] {
        kill(pids[s], libc::SIGKILL);
        run.expect(&format!(
            "supervisor: {s} (pid {}) died (signal 9)",
            pids[s]
        ));
        let l = run.expect(&format!("supervisor: restarted {s} "));
        let new = pid_of(&l);
        assert_ne!(new, pids[s]);
        pids.insert(s, new);
        run.expect(&format!("supervisor: recovered {s} "));
    }
    // A hang: the filter stops (SIGSTOP) and misses its heartbeat deadline.
    kill(pids["filter"], libc::SIGSTOP);
    run.expect(&format!(
        "supervisor: filter (pid {}) missed its heartbeat deadline",
        pids["filter"]
    ));
    run.expect("supervisor: restarted filter ");
    run.expect("supervisor: recovered filter (hang)");
    // Same number of shared-memory files as before the faults: every dead
    // process's segments were removed, every new one made its own.
    std::thread::sleep(Duration::from_secs(1));
    let after = shm_files(&prefix).len();
    assert_eq!(after, before, "{:?}", shm_files(&prefix));

    let (status, log) = run.interrupt_and_wait();
    assert!(status.success(), "{status:?}\n{}", log.join("\n"));
    let r = read_report(&report);
    for s in ["ingest", "control", "refine", "plant"] {
        assert_eq!(r["stages"][s]["restarts"], 1, "{s}");
        assert_eq!(r["stages"][s]["exit_status"], "exit 0", "{s}");
    }
    assert_eq!(r["stages"]["filter"]["restarts"], 2);
    assert_eq!(r["stages"]["filter"]["heartbeat_misses"], 1);
    assert_eq!(r["stages"]["filter"]["deaths"][1], "hang");
    let sup = &r["supervisor"];
    assert_eq!(sup["restarts"], 6);
    assert_eq!(sup["recoveries_pending"], 0, "{sup}");
    assert_eq!(sup["recovery_ms"]["count"], 6);
    assert!(sup["dead_nodes_removed"].as_u64().unwrap() >= 6, "{sup}");
    // Controls kept reaching the plant, and the filter kept beating the raw
    // measurement across its restarts (it resumed from its last belief).
    // (The counters span every incarnation of the plant.)
    let samples = r["stages"]["plant"]["processed"].as_u64().unwrap();
    let controls = r["control"]["controls_received"].as_u64().unwrap();
    assert!(
        controls * 2 > samples,
        "{controls} controls for {samples} samples"
    );
    let a = &r["accuracy"];
    assert!(a["rmse_position"].as_f64().unwrap() < a["rmse_position_raw"].as_f64().unwrap());
    // The observation books balance, and what the two dead filters could
    // never count is reported, not lost: each was down for at least a
    // restart (process start, node and ports), many sensor periods.
    let obs = &r["streams"]["observations"];
    let published = obs["published"].as_i64().unwrap();
    let counted = obs["counted"].as_i64().unwrap();
    let unaccounted = obs["unaccounted"].as_i64().unwrap();
    assert_eq!(published, counted + unaccounted, "{obs}");
    let f = &r["stages"]["filter"];
    assert_eq!(
        counted,
        f["processed"].as_i64().unwrap()
            + f["dropped"].as_i64().unwrap()
            + f["rejected"].as_i64().unwrap(),
        "{obs} {f}"
    );
    assert_eq!(
        published,
        r["stages"]["ingest"]["processed"].as_i64().unwrap()
    );
    assert!(unaccounted > 0, "{obs}");
    assert!(unaccounted < published / 2, "{obs}");
    assert!(shm_files(&prefix).is_empty(), "{:?}", shm_files(&prefix));
    assert!(beliefbus::ipc::cleanup::resources(&prefix).is_empty());
}

#[test]
fn chaos_kills_random_stages_and_the_run_still_ends_cleanly() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("chaos.json");
    let run = Run::start(&[
        "run",
        "configs/default.toml",
        "--duration",
        "10",
        "--quiet",
        "--chaos",
        "1.5",
        "--chaos-seed",
        "7",
        "--report",
        report.to_str().unwrap(),
    ]);
    let (status, log) = run.wait();
    assert!(status.success(), "{status:?}\n{}", log.join("\n"));
    let r = read_report(&report);
    let sup = &r["supervisor"];
    let kills = sup["chaos_kills"].as_u64().unwrap();
    assert!(kills >= 1, "{sup}");
    let kill_lines = log.iter().filter(|l| l.contains("chaos kills")).count() as u64;
    assert_eq!(kill_lines, kills);
    // Every kill but possibly the last few (the run ended) was restarted
    // and recovered.
    let restarts = sup["restarts"].as_u64().unwrap();
    let pending = sup["recoveries_pending"].as_u64().unwrap();
    let recovered = sup["recovery_ms"]["count"].as_u64().unwrap();
    assert!(restarts <= kills && restarts + 2 >= kills, "{sup}");
    assert_eq!(recovered + pending, restarts, "{sup}");
    assert!(recovered >= 1, "{sup}");
    let per_stage: u64 = ["ingest", "filter", "control", "refine", "plant"]
        .iter()
        .map(|s| r["stages"][s]["chaos_kills"].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(per_stage, kills);
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
}

#[test]
fn a_stage_whose_policy_forbids_restarts_ends_the_run_cleanly() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut run = Run::start(&[
        "run",
        "configs/default.toml",
        "--duration",
        "0",
        "--quiet",
        "--set",
        "stages.control.restart.on=\"never\"",
    ]);
    let prefix = run.prefix();
    let l = run.expect("supervisor: started control ");
    run.expect("supervisor: started plant ");
    kill(pid_of(&l), libc::SIGKILL);
    let (status, log) = run.wait();
    assert_eq!(status.code(), Some(1), "{}", log.join("\n"));
    assert!(
        log.iter().any(
            |l| l.contains("control stage exited unexpectedly (signal 9)")
                && l.contains("\"never\"")
        ),
        "{}",
        log.join("\n")
    );
    assert!(beliefbus::ipc::cleanup::resources(&prefix).is_empty());
}

/// Measurement for the issue note (run with `cargo test --release --test
/// reliability -- --ignored --nocapture hundred`): the run's /dev/shm file
/// count before and after 100 SIGKILL/restart cycles (round-robin over the
/// five stages, each waiting for its recovery).
#[test]
#[ignore = "measurement: 100 kill/restart cycles take minutes"]
fn hundred_kill_restart_cycles_leave_the_shared_memory_file_count_unchanged() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("hundred.json");
    let mut args = vec![
        "run",
        "configs/default.toml",
        "--duration",
        "0",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
    ];
    // Isolated crashes: the backoff series restarts after 0.2 s of life.
    let sets: Vec<String> = ["ingest", "filter", "control", "refine", "plant"]
        .iter()
        .map(|s| format!("stages.{s}.restart.reset_after_s=0.2"))
        .collect();
    for s in &sets {
        args.push("--set");
        args.push(s);
    }
    let mut run = Run::start(&args);
    let prefix = run.prefix();
    let mut pids = std::collections::HashMap::new();
    for s in ["control", "refine", "filter", "ingest", "plant"] {
        let l = run.expect(&format!("supervisor: started {s} "));
        pids.insert(s, pid_of(&l));
    }
    std::thread::sleep(Duration::from_secs(2));
    let before = shm_files(&prefix).len();
    let stages = ["filter", "ingest", "control", "refine", "plant"];
    let mut recovery_ms = Vec::new();
    for i in 0..100 {
        let s = stages[i % stages.len()];
        kill(pids[s], libc::SIGKILL);
        let l = run.expect(&format!("supervisor: restarted {s} "));
        pids.insert(s, pid_of(&l));
        let l = run.expect(&format!("supervisor: recovered {s} "));
        let ms: f64 = l
            .rsplit(" in ")
            .next()
            .and_then(|x| x.trim_end_matches(" ms").parse().ok())
            .unwrap();
        recovery_ms.push(ms);
        std::thread::sleep(Duration::from_millis(300));
    }
    std::thread::sleep(Duration::from_secs(1));
    let after = shm_files(&prefix).len();
    recovery_ms.sort_by(f64::total_cmp);
    eprintln!(
        "/dev/shm files of the run: before {before}, after 100 kill/restart cycles {after}; \
         recovery (detection → recovered) p50 {:.1} ms, max {:.1} ms",
        recovery_ms[49], recovery_ms[99]
    );
    let (status, log) = run.interrupt_and_wait();
    assert!(status.success(), "{}", log.join("\n"));
    assert_eq!(after, before);
    assert!(shm_files(&prefix).is_empty());
    let r = read_report(&report);
    assert_eq!(r["supervisor"]["restarts"], 100);
}

/// A chain snapshot received by the test (copied out of shared memory).
struct Snap {
    lineage: u64,
    version: u64,
    t_pub_ns: u64,
    words: Vec<u64>,
}

#[test]
fn a_killed_refine_resumes_its_chain_and_the_filter_keeps_its_belief() {
    use beliefbus::chain::snapshot::SnapshotView;
    use beliefbus::filter::live_chain::LiveChainFilter;
    use beliefbus::model::SdeModel;
    use beliefbus::stage::snapshots::{chain_qos, CHAIN_CHANNEL};
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let report = tmp("refine-resume.json");
    // One incremental chain (moving-frame versions are each a lineage).
    let sets = [
        "filter.backend=\"chain\"",
        "control.backend=\"none\"",
        "refine.moving_frame=false",
    ];
    let mut run = Run::start(&[
        "run",
        "configs/default.toml",
        "--duration",
        "0",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
        "--set",
        sets[0],
        "--set",
        sets[1],
        "--set",
        sets[2],
    ]);
    let prefix = run.prefix();
    run.expect("supervisor: started refine ");
    run.expect("supervisor: started plant ");
    let mut all: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    all.push(format!("run.prefix=\"{prefix}\""));
    let cfg =
        beliefbus::pipeline::config::load(&root().join("configs/default.toml"), &all).unwrap();
    let dim = cfg.model().unwrap().dims().state;
    let bus = beliefbus::ipc::Bus::open(&cfg.bus(), "watcher").unwrap();
    let sub = bus
        .slice_subscriber::<u64>(CHAIN_CHANNEL, &chain_qos(&cfg, dim), false)
        .unwrap();
    let mut seen: Vec<Snap> = Vec::new();
    let poll = |seen: &mut Vec<Snap>| {
        if let Some(s) = sub.receive_sample().unwrap() {
            let words = s.as_ref().to_vec();
            let v = SnapshotView::parse(&words).unwrap();
            seen.push(Snap {
                lineage: v.lineage,
                version: v.version,
                t_pub_ns: v.t_pub_ns,
                words,
            });
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    // A few versions of the first refine (it has been growing for a while).
    let deadline = Instant::now() + PATIENCE;
    while seen.len() < 4 {
        assert!(Instant::now() < deadline, "no chain snapshots");
        poll(&mut seen);
    }
    // The refine running now (under a loaded machine the supervisor may
    // already have restarted a slow first one for a missed heartbeat).
    run.catch_up();
    let refine_pid = run
        .log
        .iter()
        .rev()
        .find(|l| l.contains("started refine ") || l.contains("restarted refine "))
        .map(|l| pid_of(l))
        .unwrap();
    let t_kill = beliefbus::rt::clock::now_ns();
    kill(refine_pid, libc::SIGKILL);
    run.expect(&format!(
        "supervisor: refine (pid {refine_pid}) died (signal 9)"
    ));
    run.expect("supervisor: restarted refine ");
    run.expect("refine: resumed chain lineage");
    let deadline = Instant::now() + PATIENCE;
    while !seen.iter().any(|s| s.t_pub_ns > t_kill) {
        assert!(Instant::now() < deadline, "no snapshot after the restart");
        poll(&mut seen);
    }
    drop(sub);
    drop(bus);
    let before = seen.iter().rfind(|s| s.t_pub_ns < t_kill).unwrap();
    let after = seen.iter().find(|s| s.t_pub_ns > t_kill).unwrap();
    // Same chain: its lineage, newer versions, the old states' ids kept
    // (bar the few retired since).
    assert_eq!(after.lineage, before.lineage);
    assert!(
        after.version > before.version,
        "{} after {}",
        after.version,
        before.version
    );
    let (vb, va) = (
        SnapshotView::parse(&before.words).unwrap(),
        SnapshotView::parse(&after.words).unwrap(),
    );
    let kept = vb
        .ids
        .iter()
        .filter(|i| va.ids.binary_search(i).is_ok())
        .count();
    assert!(kept * 2 > vb.len(), "{kept} of {} ids kept", vb.len());
    // The filter's swap across the restart is a remap by id, not a restart
    // from the Gaussian summary: the stage's LiveChainFilter, fed the same
    // two versions.
    let model = cfg.model().unwrap();
    let prior = cfg.prior();
    let fallback = beliefbus::stage::filter::make_filter(&cfg, 0.0).unwrap();
    let mut f: LiveChainFilter<_, Vec<u64>> =
        LiveChainFilter::new(model, fallback, cfg.refine.max_states, &prior, 0.0);
    let mut swap = |words: &Vec<u64>| {
        f.offer(words.clone()).unwrap();
        loop {
            if let Some(info) = f.advance(Duration::from_secs(1)).unwrap() {
                return info;
            }
        }
    };
    assert!(swap(&before.words).from_gaussian);
    let info = swap(&after.words);
    assert!(!info.from_gaussian, "{info:?}");
    assert!(info.mass_lost < 0.5, "{info:?}");

    let (status, log) = run.interrupt_and_wait();
    assert!(status.success(), "{status:?}\n{}", log.join("\n"));
    let r = read_report(&report);
    assert!(r["stages"]["refine"]["restarts"].as_u64().unwrap() >= 1);
    assert_eq!(r["stages"]["filter"]["rejected_by_reason"]["snapshot"], 0);
    // Nothing left behind: the checkpoint (the run's state directory) and
    // the shared memory.
    let state = std::env::temp_dir().join(format!("{prefix}state"));
    assert!(!state.exists(), "{} left behind", state.display());
    assert!(shm_files(&prefix).is_empty(), "{:?}", shm_files(&prefix));
    assert!(beliefbus::ipc::cleanup::resources(&prefix).is_empty());
}
