//! External sensors end to end: `beliefbus run --sensor external` with the
//! publishers of `tools/` (Python, Rust, `beliefbus plant`) as separate
//! processes — beliefs and controls flow and the estimate tracks the
//! published truth; malformed data is rejected and counted by reason while
//! the good samples around it are still filtered; two publishers on two
//! channels are merged in measurement-time order. Every run is under the
//! test's own prefix, and nothing of it is left in shared memory.
//!
//! Pipelines run one at a time (they pin themselves to the same cores).

mod scratch_support;
mod sensor_support;
use scratch_support::Scratch;

use beliefbus::ipc::sensor_api::{monotonic_now_ns, ControlSubscriber};
use beliefbus::ipc::{Belief, Bus, BusConfig, Observation, SensorSample};
use sensor_support::*;
use serde_json::Value;
use std::process::Command;
use std::sync::Mutex;
use std::time::Duration;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

const INSTANCE: &str = "ship"; // run.instance of configs/default.toml

/// A report file, removed with its directory when the test ends.
fn report_path(name: &str) -> Scratch {
    Scratch::new("sensor", name)
}

/// `beliefbus run configs/default.toml --sensor external` under `prefix`,
/// until interrupted; returns once the stages are up.
fn start_pipeline(prefix: &TestPrefix, report: &std::path::Path, sets: &[&str]) -> ChildGuard {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_beliefbus"));
    cmd.current_dir(root()).args([
        "run",
        "configs/default.toml",
        "--sensor",
        "external",
        "--duration",
        "0",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
        "--set",
        &format!("run.prefix=\"{}\"", prefix.0),
    ]);
    for s in sets {
        cmd.args(["--set", s]);
    }
    let mut p = ChildGuard::spawn(&mut cmd);
    let bus = p.wait_line(Stream::Stderr, Duration::from_secs(60), |l| {
        l.starts_with("bus: ")
    });
    let bus = bus.unwrap_or_else(|| panic!("no bus line\n{}", p.show()));
    assert!(bus.contains(&format!("prefix={}", prefix.0)), "{bus}");
    assert!(bus.contains("sensor=beliefbus/ship/sensor"), "{bus}");
    let up = p.wait_line(Stream::Stderr, Duration::from_secs(60), |l| {
        l.starts_with("pipeline up")
    });
    assert!(up.is_some(), "pipeline did not come up\n{}", p.show());
    p
}

/// Stop the pipeline with Ctrl-C and read its report.
fn stop_pipeline(mut p: ChildGuard, report: &std::path::Path) -> (Value, ChildGuard) {
    // Let the last samples through the stages.
    std::thread::sleep(Duration::from_millis(500));
    p.interrupt();
    let status = p.finish(Duration::from_secs(60));
    assert!(
        status.is_some_and(|s| s.success()),
        "pipeline: {status:?}\n{}",
        p.show()
    );
    let r: Value = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
    (r, p)
}

/// The JSON summary a tool prints last.
fn summary(c: &ChildGuard) -> Value {
    let line = c
        .stdout
        .iter()
        .rev()
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no summary\n{}", c.show()));
    serde_json::from_str(line).unwrap()
}

fn run_tool(mut cmd: Command, limit: Duration) -> ChildGuard {
    let mut c = ChildGuard::spawn(&mut cmd);
    let status = c.finish(limit);
    assert!(status.is_some_and(|s| s.success()), "{}", c.show());
    c
}

fn python_tool(py: &std::path::Path, script: &str, args: &[&str]) -> Command {
    let a: Vec<String> = args.iter().map(|s| s.to_string()).collect();
    python_command(py, script, &a)
}

fn rust_tool(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_beliefbus-example-sensor"));
    c.args(args);
    c
}

fn u(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The checks every good external run passes: the stages processed what
/// was published, beliefs and controls flowed, the estimate beats the raw
/// measurement against the published truth.
fn check_tracking(r: &Value, published: u64) {
    assert_eq!(r["sensor_source"], "external");
    assert!(r["stages"]["plant"]["pid"].is_null() || u(&r["stages"]["plant"]["pid"]) > 0);
    let st = &r["stages"];
    assert_eq!(u(&st["ingest"]["processed"]), published, "{st}");
    assert_eq!(u(&st["ingest"]["rejected"]), 0, "{st}");
    let filtered = u(&st["filter"]["processed"]);
    assert!(
        filtered * 100 >= published * 95,
        "filtered {filtered} of {published}"
    );
    let controls = u(&st["control"]["processed"]);
    assert!(
        controls * 100 >= filtered * 90,
        "controls {controls} of {filtered}"
    );
    assert!(u(&r["hops"]["sensor->control"]["count"]) > 0);
    let a = &r["accuracy"];
    assert!(u(&a["beliefs"]) * 2 >= published, "{a}");
    assert!(
        f(&a["rmse_position"]) < f(&a["rmse_position_raw"]),
        "the filter does not beat the raw measurement: {a}"
    );
}

#[test]
fn the_python_publisher_and_actuator_close_the_loop_through_an_external_pipeline() {
    let Some(py) = python("the_python_publisher_and_actuator_close_the_loop_...") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("python.json");
    let pipeline = start_pipeline(&prefix, &report, &[]);
    let (pfx, inst) = (prefix.0.as_str(), INSTANCE);
    let mut actuator = ChildGuard::spawn(&mut python_tool(
        &py,
        "actuator.py",
        &[
            "--prefix",
            pfx,
            "--instance",
            inst,
            "--duration",
            "5",
            "--idle",
            "30",
        ],
    ));
    let publisher = run_tool(
        python_tool(
            &py,
            "sensor_publisher.py",
            &[
                "--prefix",
                pfx,
                "--instance",
                inst,
                "--duration",
                "4",
                "--truth",
                "--apply-controls",
                "--wait-ingest",
                "30",
            ],
        ),
        Duration::from_secs(120),
    );
    let act_status = actuator.finish(Duration::from_secs(60));
    assert!(
        act_status.is_some_and(|s| s.success()),
        "{}",
        actuator.show()
    );
    let (r, _p) = stop_pipeline(pipeline, &report);
    let sent = summary(&publisher);
    assert_eq!(u(&sent["good"]), 400);
    check_tracking(&r, 400);
    // Controls reached the Python actuator.
    let got = summary(&actuator);
    assert!(u(&got["summary"]["received"]) > 100, "{got}");
}

#[test]
fn the_rust_publisher_feeds_an_external_pipeline_and_controls_flow() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("rust.json");
    let pipeline = start_pipeline(&prefix, &report, &[]);
    let pfx = prefix.0.clone();
    // An actuator in Rust, counting the controls while the sensor runs.
    let actuator = std::thread::spawn(move || {
        let mut act = ControlSubscriber::connect(INSTANCE, &pfx).unwrap();
        let mut last_seq = None;
        while let Some(c) = act.wait(Duration::from_secs(3)).unwrap() {
            assert!(c.dim == 2 && c.u[..2].iter().all(|v| v.is_finite()));
            assert!(last_seq.is_none_or(|l| c.header.seq > l));
            last_seq = Some(c.header.seq);
        }
        act.received()
    });
    let publisher = run_tool(
        rust_tool(&[
            "--prefix",
            &prefix.0,
            "--instance",
            INSTANCE,
            "--duration",
            "4",
            "--truth",
            "--apply-controls",
            "--wait-ingest",
            "30",
        ]),
        Duration::from_secs(120),
    );
    let controls = actuator.join().unwrap();
    let (r, _p) = stop_pipeline(pipeline, &report);
    assert_eq!(u(&summary(&publisher)["good"]), 400);
    check_tracking(&r, 400);
    assert!(controls > 100, "the actuator got {controls} controls");
}

#[test]
fn beliefbus_plant_is_an_external_publisher_like_any_other() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("plant.json");
    let pipeline = start_pipeline(&prefix, &report, &[]);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_beliefbus"));
    cmd.current_dir(root()).args([
        "plant",
        "configs/default.toml",
        "--duration",
        "4",
        "--prefix",
        &prefix.0,
    ]);
    let plant = run_tool(cmd, Duration::from_secs(120));
    let (r, _p) = stop_pipeline(pipeline, &report);
    let s = summary(&plant);
    assert_eq!(u(&s["samples"]), 400);
    check_tracking(&r, 400);
    // Its statistics reached the launcher: the closed loop is reported.
    assert!(u(&r["stages"]["plant"]["pid"]) > 0);
    assert_eq!(u(&r["stages"]["plant"]["processed"]), 400);
    assert!(
        u(&r["control"]["controls_received"]) > 300,
        "{}",
        r["control"]
    );
    assert_eq!(
        u(&s["controls_received"]),
        u(&r["control"]["controls_received"])
    );
}

/// Rate rejections of the burst: the ingest token bucket (3 samples,
/// refilled at `rate_hz` on measurement time) recomputed for the nominal
/// samples `period_ns` apart before the burst and the `n` burst samples
/// `spacing_ns` apart.
fn expected_rate_rejections(period_ns: u64, n: u64, spacing_ns: u64, rate_hz: f64) -> u64 {
    let burst = beliefbus::stage::ingest::RATE_BURST;
    let mut tokens = burst;
    let mut rejected = 0;
    let nominal = std::iter::repeat_n((period_ns, false), 50);
    let steps = nominal.chain(std::iter::repeat_n((spacing_ns, true), n as usize));
    for (dt, in_burst) in steps {
        tokens = (tokens + dt as f64 * 1e-9 * rate_hz).min(burst);
        if tokens < 1.0 {
            assert!(in_burst, "the nominal rate must pass the limiter");
            rejected += 1;
        } else {
            tokens -= 1.0;
        }
    }
    rejected
}

const FAULT_RATE_HZ: f64 = 130.0;

fn fault_sets() -> Vec<String> {
    vec![format!(
        "ingest.channels=[{{id = 0, components = [0, 1], max_rate_hz = {FAULT_RATE_HZ}}}]"
    )]
}

/// The malformed-data run: every injected fault counted under its reason,
/// the burst's excess under `rate`, the good samples filtered.
fn check_faults(r: &Value, pipeline: &ChildGuard, sent: &Value) {
    let good = u(&sent["good"]);
    let injected = sent["injected"].as_object().expect("injected");
    let burst = &sent["burst"];
    let rate = expected_rate_rejections(
        u(&sent["period_ns"]),
        u(&burst["n"]),
        u(&burst["spacing_ns"]),
        FAULT_RATE_HZ,
    );
    assert!(rate > 10, "the burst must exceed the limit: {rate}");
    let ingest = &r["stages"]["ingest"];
    let by = &ingest["rejected_by_reason"];
    for reason in [
        "non_finite",
        "dimension",
        "time_backwards",
        "duplicate",
        "unknown_channel",
        "too_old",
    ] {
        let want = injected.get(reason).map(u).unwrap_or(0);
        assert!(want > 0, "{reason} was not injected: {sent}");
        assert_eq!(u(&by[reason]), want, "{reason}: {by}");
    }
    assert_eq!(u(&by["rate"]), rate, "rate: {by}");
    assert_eq!(u(&by["invalid"]), 0, "{by}");
    let bad: u64 = injected.values().map(u).sum::<u64>() + rate;
    assert_eq!(u(&ingest["rejected"]), bad);
    // Every good sample but the burst's excess is filtered.
    assert_eq!(u(&ingest["processed"]), good - rate);
    assert_eq!(u(&ingest["dropped"]), 0);
    let filtered = u(&r["stages"]["filter"]["processed"]);
    assert!(filtered * 100 >= (good - rate) * 95, "filtered {filtered}");
    for s in ["ingest", "filter", "control", "refine"] {
        assert_eq!(r["stages"][s]["exit_status"], "exit 0", "{s} crashed");
    }
    let a = &r["accuracy"];
    assert!(f(&a["rmse_position"]) < f(&a["rmse_position_raw"]), "{a}");
    // Logged, at a bounded rate: some lines, at most one per reason per
    // second (+1 for the first).
    let lines: Vec<&String> = pipeline
        .stderr
        .iter()
        .filter(|l| l.contains("rejected sample ("))
        .collect();
    assert!(!lines.is_empty(), "{}", pipeline.show());
    let secs = 4 + 2; // publishing time + slack
    for reason in ["non_finite", "duplicate", "rate"] {
        let n = lines
            .iter()
            .filter(|l| l.contains(&format!("({reason})")))
            .count();
        assert!(n >= 1 && n <= secs + 1, "{n} lines for {reason}");
    }
}

#[test]
fn malformed_python_samples_are_rejected_by_reason_and_the_good_ones_filtered() {
    let Some(py) = python("malformed_python_samples_are_rejected_...") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("faults-python.json");
    let sets = fault_sets();
    let pipeline = start_pipeline(&prefix, &report, &[sets[0].as_str()]);
    let publisher = run_tool(
        python_tool(
            &py,
            "sensor_publisher.py",
            &[
                "--prefix",
                &prefix.0,
                "--instance",
                INSTANCE,
                "--duration",
                "4",
                "--truth",
                "--apply-controls",
                "--faults",
                "--wait-ingest",
                "30",
            ],
        ),
        Duration::from_secs(120),
    );
    let (r, p) = stop_pipeline(pipeline, &report);
    check_faults(&r, &p, &summary(&publisher));
}

#[test]
fn malformed_rust_samples_are_rejected_by_reason_and_the_good_ones_filtered() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("faults-rust.json");
    let sets = fault_sets();
    let pipeline = start_pipeline(&prefix, &report, &[sets[0].as_str()]);
    let publisher = run_tool(
        rust_tool(&[
            "--prefix",
            &prefix.0,
            "--instance",
            INSTANCE,
            "--duration",
            "4",
            "--truth",
            "--apply-controls",
            "--faults",
            "--wait-ingest",
            "30",
        ]),
        Duration::from_secs(120),
    );
    let (r, p) = stop_pipeline(pipeline, &report);
    check_faults(&r, &p, &summary(&publisher));
}

/// Position on the shared circle at `t_ns`.
fn circle(t0: u64, t_ns: u64) -> (f64, f64) {
    let a = OMEGA * (t_ns as f64 - t0 as f64) * 1e-9;
    (RADIUS * a.cos(), RADIUS * a.sin())
}
const RADIUS: f64 = 5.0;
const OMEGA: f64 = 0.3;

#[test]
fn two_publishers_on_two_channels_are_merged_and_tracked() {
    let Some(py) = python("two_publishers_on_two_channels_are_merged_and_tracked") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = TestPrefix::new();
    let report = report_path("multi.json");
    // Range from one sensor (channel 1), bearing from another (channel 2).
    let pipeline = start_pipeline(
        &prefix,
        &report,
        &[
            "ingest.channels=[{id = 1, components = [0]}, {id = 2, components = [1]}]",
            "ingest.reorder_window_ms=100.0",
            "filter.prior_mean=[5.0, 0.0, 0.0, 1.5]",
            // The circle ignores controls; a controller would make the
            // filter predict forces that never act.
            "control.backend=\"none\"",
        ],
    );
    let cfg = BusConfig {
        prefix: prefix.0.clone(),
        instance: INSTANCE.into(),
    };
    let bus = Bus::open(&cfg, "test-monitor").unwrap();
    let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
    let samples = bus.subscriber_with::<SensorSample>(256, false).unwrap();
    let obs = bus.subscriber_with::<Observation>(32, false).unwrap();

    let t0 = monotonic_now_ns().to_string();
    let common = |ch: &'static str, comp: &'static str, rate: &'static str| {
        vec![
            "--prefix".to_string(),
            prefix.0.clone(),
            "--instance".into(),
            INSTANCE.into(),
            "--trajectory".into(),
            "circle".into(),
            "--t0-ns".into(),
            t0.clone(),
            "--channel".into(),
            ch.into(),
            "--components".into(),
            comp.into(),
            "--rate".into(),
            rate.into(),
            "--duration".into(),
            "4".into(),
            "--wait-ingest".into(),
            "30".into(),
        ]
    };
    let mut py_range = ChildGuard::spawn(&mut python_command(
        &py,
        "sensor_publisher.py",
        &common("1", "range", "100"),
    ));
    let mut rs_bearing = ChildGuard::spawn(rust_tool(&[]).args(common("2", "bearing", "70")));
    let (mut b, mut s, mut o) = (Vec::new(), Vec::new(), Vec::new());
    while py_range.running() || rs_bearing.running() {
        while let Some(x) = beliefs.receive().unwrap() {
            b.push(x);
        }
        while let Some(x) = samples.receive().unwrap() {
            s.push(x);
        }
        while let Some(x) = obs.receive().unwrap() {
            o.push(x);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    for c in [&mut py_range, &mut rs_bearing] {
        let st = c.finish(Duration::from_secs(30));
        assert!(st.is_some_and(|s| s.success()), "{}", c.show());
    }
    let published = u(&summary(&py_range)["good"]) + u(&summary(&rs_bearing)["good"]);
    assert_eq!(published, 400 + 280);
    std::thread::sleep(Duration::from_millis(300));
    while let Some(x) = beliefs.receive().unwrap() {
        b.push(x);
    }
    while let Some(x) = obs.receive().unwrap() {
        o.push(x);
    }
    drop((beliefs, samples, obs, bus));
    let (r, _p) = stop_pipeline(pipeline, &report);

    // Merged: one time-ordered stream with each channel's component.
    assert!(o
        .windows(2)
        .all(|w| w[0].header.t_valid_ns <= w[1].header.t_valid_ns));
    assert!(o.iter().any(|x| x.channel == 1 && x.mask == 0b01));
    assert!(o.iter().any(|x| x.channel == 2 && x.mask == 0b10));
    let ingest = &r["stages"]["ingest"];
    let late = u(&ingest["rejected_by_reason"]["too_old"]);
    assert_eq!(
        u(&ingest["rejected"]),
        late,
        "only late samples may be refused"
    );
    assert!(late * 100 <= published, "{late} late of {published}");
    assert_eq!(u(&ingest["processed"]) + late, published);

    // Tracking: beliefs after 1.5 s against the circle, versus the raw fix
    // from each bearing and the latest range before it.
    let t0: u64 = t0.parse().unwrap();
    let after = t0 + 1_500_000_000;
    let (mut se, mut n) = (0.0, 0);
    for x in b.iter().filter(|x| x.header.t_valid_ns > after) {
        let (cx, cy) = circle(t0, x.header.t_valid_ns);
        se += (x.mean[0] - cx).powi(2) + (x.mean[1] - cy).powi(2);
        n += 1;
    }
    assert!(n > 200, "{n} beliefs after the warm-up");
    let rmse = (se / n as f64).sqrt();
    s.sort_by_key(|x| x.t_meas_ns);
    let (mut se_raw, mut n_raw, mut range) = (0.0, 0, None);
    for x in &s {
        match x.channel {
            1 => range = Some(x.values[0]),
            2 if x.t_meas_ns > after => {
                if let Some(rg) = range {
                    let (cx, cy) = circle(t0, x.t_meas_ns);
                    let (px, py) = (rg * x.values[0].cos(), rg * x.values[0].sin());
                    se_raw += (px - cx).powi(2) + (py - cy).powi(2);
                    n_raw += 1;
                }
            }
            _ => {}
        }
    }
    let rmse_raw = (se_raw / n_raw.max(1) as f64).sqrt();
    assert!(n_raw > 100);
    assert!(
        rmse < 0.5 * rmse_raw,
        "filter {rmse:.3} vs raw range+bearing {rmse_raw:.3}"
    );
}
