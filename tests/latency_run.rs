//! `beliefbus latency` end to end: two real processes, ours and bare
//! interleaved, the JSON schema, consistent ratios, plots and HdrHistogram
//! logs, and no shared memory left — after a normal run, after Ctrl-C, and
//! after the pong process is killed. No latency value is asserted.

use beliefbus::ipc::cleanup;
use serde_json::Value;
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_beliefbus")
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("bb-lat-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Every run prefix the process `pid` created (`iox2_bb-<pid>-…`).
fn leftovers(pid: u32) -> Vec<PathBuf> {
    cleanup::resources(&format!("{}{pid:x}-", cleanup::RUN_STEM))
}

/// Wait for `child` with a watchdog (a hung run fails the test instead of
/// hanging it).
fn wait(child: &mut Child, limit: Duration) -> ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if t.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("beliefbus latency did not finish within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn block_keys(v: &Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn a_short_run_measures_ours_and_bare_and_leaves_nothing() {
    let dir = tmp_dir("run");
    let json = dir.join("l.json");
    let svg = dir.join("l.svg");
    let hdr = dir.join("hdr");
    let mut child = Command::new(exe())
        .args(["latency", "--duration", "1.5", "--payload", "control,64,1M"])
        .arg("--json")
        .arg(&json)
        .arg("--plot")
        .arg(&svg)
        .arg("--hdr")
        .arg(&hdr)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let status = wait(&mut child, Duration::from_secs(120));
    assert!(status.success(), "{status}");
    assert!(leftovers(pid).is_empty(), "{:?}", leftovers(pid));

    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let paths = v["paths"].as_array().unwrap();
    let names: Vec<&str> = paths.iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["control", "chain-64B", "chain-1MiB"]);
    let want_block: BTreeSet<String> = ["count", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for p in paths {
        for key in [
            "name",
            "mode",
            "payload_bytes",
            "ours",
            "bare",
            "ratio_p50",
            "ratio_p99",
        ] {
            assert!(p.get(key).is_some(), "{key} missing in {p}");
        }
        assert_eq!(p["mode"], "event");
        for side in ["ours", "bare"] {
            assert_eq!(block_keys(&p[side]), want_block);
            let b = &p[side];
            assert!(b["count"].as_u64().unwrap() > 0, "{side} of {}", p["name"]);
            let vals: Vec<f64> = ["p50_us", "p90_us", "p99_us", "p999_us", "max_us"]
                .iter()
                .map(|k| b[k].as_f64().unwrap())
                .collect();
            assert!(vals[0] > 0.0);
            assert!(vals.windows(2).all(|w| w[0] <= w[1]), "{vals:?}");
        }
        for (r, q) in [
            ("ratio_p50", "p50_us"),
            ("ratio_p90", "p90_us"),
            ("ratio_p99", "p99_us"),
            ("ratio_p999", "p999_us"),
            ("ratio_max", "max_us"),
        ] {
            let want = p["ours"][q].as_f64().unwrap() / p["bare"][q].as_f64().unwrap();
            let got = p[r].as_f64().unwrap();
            assert!((got - want).abs() <= 1e-12 * want, "{r}: {got} vs {want}");
        }
    }
    assert_eq!(paths[0]["payload_bytes"], 184);
    assert_eq!(paths[2]["payload_bytes"], 1 << 20);
    assert_eq!(v["run"]["shm_left"], 0);

    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.contains("chain-1MiB") && svg.contains("bare iceoryx2"));
    for name in ["control", "chain-64B", "chain-1MiB"] {
        for side in ["ours", "bare"] {
            let log = std::fs::read_to_string(hdr.join(format!("{name}.{side}.hlog"))).unwrap();
            assert!(log.contains("#[StartTime:"));
            // One interval line per measured slot (at least four rounds).
            let intervals = log.lines().filter(|l| !l.starts_with('#')).count();
            assert!(intervals >= 4, "{name}.{side}: {intervals}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn spin_and_hybrid_modes_run() {
    for mode in ["spin", "hybrid"] {
        let dir = tmp_dir(mode);
        let json = dir.join("l.json");
        let mut child = Command::new(exe())
            .args([
                "latency",
                "--duration",
                "0.6",
                "--payload",
                "belief",
                "--mode",
                mode,
            ])
            .arg("--json")
            .arg(&json)
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let pid = child.id();
        let status = wait(&mut child, Duration::from_secs(120));
        assert!(status.success(), "{mode}: {status}");
        assert!(leftovers(pid).is_empty());
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let p = &v["paths"][0];
        assert_eq!(p["mode"], mode);
        assert!(p["ours"]["count"].as_u64().unwrap() > 0);
        assert!(p["bare"]["count"].as_u64().unwrap() > 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// Start a long run and wait until it measures (its stderr says so).
fn start_long_run() -> Child {
    let mut child = Command::new(exe())
        .args(["latency", "--duration", "60", "--payload", "observation,4K"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    while line.is_empty() || !line.contains("measuring") {
        line.clear();
        assert!(err.read_line(&mut line).unwrap() > 0, "no 'measuring' line");
    }
    // Keep draining stderr so the child never blocks on a full pipe.
    std::thread::spawn(move || {
        let mut sink = String::new();
        while err.read_line(&mut sink).map(|n| n > 0).unwrap_or(false) {
            sink.clear();
        }
    });
    std::thread::sleep(Duration::from_millis(1500));
    child
}

/// The pong process of the run `parent`.
fn pong_of(parent: u32) -> Option<u32> {
    let task = format!("/proc/{parent}/task");
    for t in std::fs::read_dir(task).ok()?.flatten() {
        let kids = std::fs::read_to_string(t.path().join("children")).unwrap_or_default();
        if let Some(k) = kids.split_whitespace().next() {
            return k.parse().ok();
        }
    }
    None
}

#[test]
fn ctrl_c_stops_the_run_and_cleans_up() {
    let mut child = start_long_run();
    let pid = child.id();
    let pong = pong_of(pid).expect("a pong process");
    // SAFETY: signalling our own child.
    unsafe { libc::kill(pid as i32, libc::SIGINT) };
    let status = wait(&mut child, Duration::from_secs(30));
    assert!(status.success(), "{status}");
    assert!(leftovers(pid).is_empty(), "{:?}", leftovers(pid));
    assert!(
        !std::path::Path::new(&format!("/proc/{pong}")).exists()
            || std::fs::read_to_string(format!("/proc/{pong}/stat"))
                .map(|s| s.contains(") Z "))
                .unwrap_or(true),
        "the pong process outlived the run"
    );
}

#[test]
fn a_killed_pong_ends_the_run_with_an_error_and_cleans_up() {
    let mut child = start_long_run();
    let pid = child.id();
    let pong = pong_of(pid).expect("a pong process");
    // SAFETY: signalling our grandchild.
    unsafe { libc::kill(pong as i32, libc::SIGKILL) };
    let status = wait(&mut child, Duration::from_secs(60));
    assert!(!status.success());
    assert!(leftovers(pid).is_empty(), "{:?}", leftovers(pid));
}

#[test]
fn bad_arguments_exit_2_with_one_line() {
    for args in [
        vec!["latency", "--payload", "12"],
        vec!["latency", "--duration=0"],
        vec!["latency", "--cores", "0"],
        vec!["latency", "--cores", "0,4096"],
        vec!["jitter", "--rate", "0"],
    ] {
        let out = Command::new(exe()).args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
    }
}
