//! `beliefbus jitter` end to end: the timer baseline on every core, the JSON
//! schema (the same percentile block for the baseline, each core and each
//! pipeline path), plots and HdrHistogram logs. No timing value is asserted.

use serde_json::Value;
use std::collections::BTreeSet;
use std::process::Command;

fn keys(v: &Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn the_timer_baseline_runs_on_every_core_and_reports_blocks() {
    let dir = std::env::temp_dir().join(format!("bb-jit-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("j.json");
    let out = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args([
            "jitter",
            "--timer-only",
            "--duration",
            "1.2",
            "--rate",
            "500",
            "--stress",
            "1",
        ])
        .arg("--json")
        .arg(&json)
        .arg("--plot")
        .arg(dir.join("j.svg"))
        .arg("--hdr")
        .arg(dir.join("hdr"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let block: BTreeSet<String> = ["count", "p50_us", "p90_us", "p99_us", "p999_us", "max_us"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let entry: BTreeSet<String> = [
        "name",
        "core",
        "period_jitter",
        "latency",
        "deadline_misses",
        "missed_periods",
        "budget_us",
        "ratio_p50",
        "ratio_p99",
        "latency_ratio_p50",
        "latency_ratio_p99",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    assert_eq!(v["rate_hz"], 500.0);
    assert_eq!(v["stress_cpu_threads"], 1);
    assert_eq!(v["stress_mem_threads"], 1);
    let base = &v["baseline"];
    assert_eq!(keys(base), entry);
    assert_eq!(base["name"], "timer");
    assert_eq!(base["budget_us"], 2000.0);
    assert_eq!(keys(&base["period_jitter"]), block);
    assert_eq!(keys(&base["latency"]), block);
    let cores = v["cores"].as_array().unwrap();
    let n = beliefbus::rt::sched::available_cores();
    assert_eq!(cores.len(), n);
    let mut total = 0;
    for (i, c) in cores.iter().enumerate() {
        assert_eq!(keys(c), entry);
        assert_eq!(c["core"], i);
        let wakes = c["latency"]["count"].as_u64().unwrap();
        let misses = c["deadline_misses"].as_u64().unwrap();
        // 1.2 s at 500 Hz: 600 deadlines, each woken or missed.
        assert_eq!(wakes + misses, 600, "core {i}");
        assert_eq!(c["period_jitter"]["count"].as_u64().unwrap() + 1, wakes);
        total += wakes;
    }
    assert_eq!(base["latency"]["count"].as_u64().unwrap(), total);
    assert!(v["paths"].is_array());
    // The stall probe ran on every core for --duration (1.2 s), at the
    // fixed thresholds (no pipeline), its rates falling with the threshold.
    let stalls = v["host_stalls"].as_array().unwrap();
    assert_eq!(stalls.len(), n);
    let fixed: Vec<f64> = beliefbus::latency::jitter::THRESHOLDS_US.to_vec();
    for (i, r) in stalls.iter().enumerate() {
        assert_eq!(r["core"], i);
        let spun = r["spun_s"].as_f64().unwrap();
        assert!(spun > 0.0 && spun <= 1.2, "{r}");
        let t: Vec<f64> = serde_json::from_value(r["thresholds_us"].clone()).unwrap();
        assert_eq!(t, fixed);
        for k in ["charged_per_min", "steal_per_min", "switched_per_min"] {
            let x: Vec<f64> = serde_json::from_value(r[k].clone()).unwrap();
            assert_eq!(x.len(), t.len());
            assert!(
                x.windows(2).all(|w| w[0] >= w[1] && w[1] >= 0.0),
                "{k}: {x:?}"
            );
        }
    }
    for c in 0..n {
        for what in ["wake", "period-jitter"] {
            let f = dir.join("hdr").join(format!("timer-core{c}.{what}.hlog"));
            assert!(std::fs::read_to_string(&f)
                .unwrap()
                .contains("#[StartTime:"));
        }
    }
    assert!(std::fs::read_to_string(dir.join("j.svg"))
        .unwrap()
        .contains("timer core 0"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_pipeline_is_measured_against_the_timer_in_the_same_run() {
    let dir = std::env::temp_dir().join(format!("bb-jitp-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("j.json");
    // The crate root holds configs/ (cargo runs tests from there).
    let out = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(["jitter", "--duration", "1", "--set", "filter.backend=ekf"])
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["rate_hz"], 1000.0, "the rate of configs/ship-1khz.toml");
    assert_eq!(v["shm_left"], 0);
    let paths = v["paths"].as_array().unwrap();
    let names: Vec<&str> = paths.iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["control", "sensor"]);
    let base = &v["baseline"];
    for p in paths {
        assert_eq!(keys(p), keys(base));
        assert!(p["period_jitter"]["count"].as_u64().unwrap() > 0, "{p}");
        assert!(p["latency"]["count"].as_u64().unwrap() > 0, "{p}");
        // Ratios are the blocks' quotients.
        for (r, block, q) in [
            ("ratio_p50", "period_jitter", "p50_us"),
            ("ratio_p99", "period_jitter", "p99_us"),
            ("latency_ratio_p50", "latency", "p50_us"),
            ("latency_ratio_p99", "latency", "p99_us"),
        ] {
            let want = p[block][q].as_f64().unwrap() / base[block][q].as_f64().unwrap();
            let got = p[r].as_f64().unwrap();
            assert!((got - want).abs() <= 1e-12 * want, "{r}: {got} vs {want}");
        }
    }
    let control = &paths[0];
    // The end-to-end budget is ingest + filter + control of the config.
    assert_eq!(control["budget_us"], 50.0 + 300.0 + 700.0);
    let pipe = &v["pipeline"];
    assert!(pipe["controls"].as_u64().unwrap() > 0);
    for stage in ["ingest", "filter", "control", "refine", "plant"] {
        let s = &pipe["stages"][stage];
        // Refine is anytime work at the lowest priority: its first round
        // builds the initial chain, which can outlast this 1 s run before
        // it takes a belief; it must report, not necessarily have processed.
        if stage == "refine" {
            assert!(s["processed"].is_u64(), "{stage}");
        } else {
            assert!(s["processed"].as_u64().unwrap() > 0, "{stage}");
        }
        assert!(s["deadline_misses"].is_u64(), "{stage}");
        assert!(s["budget_us"].as_f64().unwrap() > 0.0, "{stage}");
        assert!(s["late"].is_u64(), "{stage}");
        // (null for a refine whose first round has not finished, as above)
        assert!(
            s["lateness_p99_us"].is_f64() || (stage == "refine" && s["lateness_p99_us"].is_null()),
            "{stage}"
        );
    }
    assert!(pipe["hops"]["sensor->control"]["count"].as_u64().unwrap() > 0);
    // The stall probe's thresholds include every stage's budget, so each
    // stage's misses can be set beside the host stalls longer than it.
    for r in v["host_stalls"].as_array().unwrap() {
        let t: Vec<f64> = serde_json::from_value(r["thresholds_us"].clone()).unwrap();
        for stage in ["ingest", "filter", "control", "plant"] {
            let b = pipe["stages"][stage]["budget_us"].as_f64().unwrap();
            assert!(t.contains(&b), "{stage} {b} not in {t:?}");
            assert!(pipe["stages"][stage]["core"].is_u64(), "{stage}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
