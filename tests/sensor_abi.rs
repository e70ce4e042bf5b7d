//! Sensor ABI v1 across languages: the layouts documented in
//! `docs/sensor-abi.md` are pinned at compile time, the Python ctypes
//! structures of `tools/python` agree with them field by field, and samples
//! and controls cross between a Python and a Rust process byte-exactly, with
//! either side creating the services (so the documented QoS is compatible
//! with `crates/beliefbus-ipc/src/ports.rs`).

mod sensor_support;

use beliefbus::ipc::sensor_api::wire_type_name;
use beliefbus::ipc::{Bus, BusConfig, Control, Message, SensorSample, Trace, Truth};
use sensor_support::*;
use serde_json::Value;
use std::mem::{align_of, offset_of, size_of};
use std::time::Duration;

// The published contract: fails to compile if a layout drifts.
const _: () = {
    assert!(size_of::<SensorSample>() == 232 && align_of::<SensorSample>() == 8);
    assert!(offset_of!(SensorSample, seq) == 0);
    assert!(offset_of!(SensorSample, t_meas_ns) == 8);
    assert!(offset_of!(SensorSample, t_pub_ns) == 16);
    assert!(offset_of!(SensorSample, channel) == 24);
    assert!(offset_of!(SensorSample, dim) == 28);
    assert!(offset_of!(SensorSample, flags) == 32);
    assert!(offset_of!(SensorSample, reserved0) == 36);
    assert!(offset_of!(SensorSample, values) == 40);
    assert!(offset_of!(SensorSample, noise_std) == 104);
    assert!(offset_of!(SensorSample, reserved) == 168);

    assert!(size_of::<Trace>() == 80);
    assert!(size_of::<Control>() == 184 && align_of::<Control>() == 8);
    assert!(offset_of!(Control, header) == 0);
    assert!(offset_of!(Control, trace) == 24);
    assert!(offset_of!(Control, dim) == 104);
    assert!(offset_of!(Control, status) == 108);
    assert!(offset_of!(Control, u) == 112);
    assert!(offset_of!(Control, cost) == 144);
    assert!(offset_of!(Control, goal) == 152);
    assert!(offset_of!(Control, waypoint_index) == 168);
    assert!(offset_of!(Control, reserved) == 172);
    assert!(offset_of!(Control, waypoints_reached) == 176);

    assert!(size_of::<Truth>() == 200 && align_of::<Truth>() == 8);
    assert!(offset_of!(Truth, x) == 40);
    assert!(offset_of!(Truth, u) == 104);
    assert!(offset_of!(Truth, y) == 136);
};

#[test]
fn type_names_are_the_documented_ones() {
    assert_eq!(
        wire_type_name::<SensorSample>(),
        "beliefbus.SensorSample.v1"
    );
    assert_eq!(wire_type_name::<Control>(), "beliefbus.Control.v1");
    assert_eq!(wire_type_name::<Truth>(), "beliefbus.Truth.v1");
    assert_eq!(SensorSample::CHANNEL, "sensor");
    assert_eq!(Control::CHANNEL, "control");
}

/// (field, offset) of each top-level field, as Rust lays them out.
fn rust_layout<M: Message>() -> (usize, usize, Vec<(&'static str, usize)>) {
    let fields: Vec<(&'static str, usize)> = match M::CHANNEL {
        "sensor" => vec![
            ("seq", offset_of!(SensorSample, seq)),
            ("t_meas_ns", offset_of!(SensorSample, t_meas_ns)),
            ("t_pub_ns", offset_of!(SensorSample, t_pub_ns)),
            ("channel", offset_of!(SensorSample, channel)),
            ("dim", offset_of!(SensorSample, dim)),
            ("flags", offset_of!(SensorSample, flags)),
            ("reserved0", offset_of!(SensorSample, reserved0)),
            ("values", offset_of!(SensorSample, values)),
            ("noise_std", offset_of!(SensorSample, noise_std)),
            ("reserved", offset_of!(SensorSample, reserved)),
        ],
        "control" => vec![
            ("header", offset_of!(Control, header)),
            ("trace", offset_of!(Control, trace)),
            ("dim", offset_of!(Control, dim)),
            ("status", offset_of!(Control, status)),
            ("u", offset_of!(Control, u)),
            ("cost", offset_of!(Control, cost)),
            ("goal", offset_of!(Control, goal)),
            ("waypoint_index", offset_of!(Control, waypoint_index)),
            ("reserved", offset_of!(Control, reserved)),
            ("waypoints_reached", offset_of!(Control, waypoints_reached)),
        ],
        "truth" => vec![
            ("header", offset_of!(Truth, header)),
            ("channel", offset_of!(Truth, channel)),
            ("dim", offset_of!(Truth, dim)),
            ("obs_dim", offset_of!(Truth, obs_dim)),
            ("control_dim", offset_of!(Truth, control_dim)),
            ("x", offset_of!(Truth, x)),
            ("u", offset_of!(Truth, u)),
            ("y", offset_of!(Truth, y)),
        ],
        other => panic!("no layout for {other}"),
    };
    (size_of::<M>(), align_of::<M>(), fields)
}

fn check_python_layout<M: Message>(py: &Value, name: &str) {
    let d = &py[name];
    let (size, align, fields) = rust_layout::<M>();
    assert_eq!(d["type_name"], wire_type_name::<M>(), "{name} type name");
    assert_eq!(d["size"], size, "{name} size");
    assert_eq!(d["alignment"], align, "{name} alignment");
    let offsets = d["offsets"].as_object().expect("offsets");
    assert_eq!(offsets.len(), fields.len(), "{name}: {offsets:?}");
    for (f, off) in fields {
        assert_eq!(offsets[f], off, "{name}.{f} offset");
    }
}

#[test]
fn python_ctypes_layouts_match_rust() {
    let Some(py) = python("python_ctypes_layouts_match_rust") else {
        return;
    };
    let mut c = ChildGuard::spawn(&mut python_command(
        &py,
        "sensor_publisher.py",
        &["--print-abi".into()],
    ));
    let status = c.finish(Duration::from_secs(60));
    assert!(status.is_some_and(|s| s.success()), "{}", c.show());
    let v: Value = serde_json::from_str(&c.stdout.join("\n")).expect("JSON");
    check_python_layout::<SensorSample>(&v, "SensorSample");
    check_python_layout::<Control>(&v, "Control");
    check_python_layout::<Truth>(&v, "Truth");
}

/// Sample `k` of the pattern of `sensor_publisher.py --pattern` (every
/// field distinct, exactly representable).
fn pattern(k: u64) -> SensorSample {
    let mut s = SensorSample {
        seq: k,
        t_meas_ns: 1_000_000_000_000 + 1000 * k,
        t_pub_ns: 2_000_000_000_000 + 1000 * k,
        channel: 7 + (k % 3) as u32,
        dim: 1 + (k % 8) as u32,
        flags: (k % 2) as u32,
        reserved0: 0xA5A5_0000 + k as u32,
        ..SensorSample::default()
    };
    for j in 0..8 {
        s.values[j] = k as f64 + j as f64 / 8.0 - 3.0;
        s.noise_std[j] = (k + 1) as f64 * 0.5f64.powi(j as i32);
        s.reserved[j] = 0x0102_0304_0506_0708 * (j as u64 + 1) + k;
    }
    s
}

const N_PATTERN: u64 = 40;

fn bus(prefix: &TestPrefix, node: &str) -> Bus {
    let cfg = BusConfig {
        prefix: prefix.0.clone(),
        instance: "abi".into(),
    };
    Bus::open(&cfg, node).unwrap()
}

fn pattern_args(prefix: &TestPrefix) -> Vec<String> {
    vec![
        "--prefix".into(),
        prefix.0.clone(),
        "--instance".into(),
        "abi".into(),
        "--pattern".into(),
        N_PATTERN.to_string(),
        "--wait-ingest".into(),
        "30".into(),
    ]
}

fn expect_pattern(sub: &beliefbus::ipc::Subscriber<SensorSample>) {
    let mut got = Vec::new();
    let _ = poll(Duration::from_secs(10), || {
        while let Some(s) = sub.receive().unwrap() {
            got.push(s);
        }
        (got.len() as u64 >= N_PATTERN).then_some(())
    });
    assert_eq!(got.len() as u64, N_PATTERN);
    for (k, s) in got.iter().enumerate() {
        assert_eq!(*s, pattern(k as u64), "sample {k} differs");
    }
}

#[test]
fn python_samples_reach_a_rust_subscriber_intact() {
    let Some(py) = python("python_samples_reach_a_rust_subscriber_intact") else {
        return;
    };
    let prefix = TestPrefix::new();
    {
        // Rust creates the service (as ingest does); Python opens it.
        let b = bus(&prefix, "ingest");
        let sub = b.subscriber_with::<SensorSample>(256, true).unwrap();
        let mut c = ChildGuard::spawn(&mut python_command(
            &py,
            "sensor_publisher.py",
            &pattern_args(&prefix),
        ));
        expect_pattern(&sub);
        let status = c.finish(Duration::from_secs(60));
        assert!(status.is_some_and(|s| s.success()), "{}", c.show());
    }
}

#[test]
fn a_service_created_by_python_is_opened_by_rust_with_its_qos() {
    let Some(py) = python("a_service_created_by_python_is_opened_by_rust_with_its_qos") else {
        return;
    };
    let prefix = TestPrefix::new();
    {
        let mut c = ChildGuard::spawn(&mut python_command(
            &py,
            "sensor_publisher.py",
            &pattern_args(&prefix),
        ));
        // Python has created the sensor service before Rust touches it.
        let ready = c.wait_line(Stream::Stderr, Duration::from_secs(30), |l| {
            l.contains("publisher ready")
        });
        assert!(ready.is_some(), "{}", c.show());
        // Rust opens it with crates/beliefbus-ipc/src/ports.rs's settings: this fails if the
        // Python side created it with smaller limits or another type.
        let b = bus(&prefix, "ingest");
        let sub = b.subscriber_with::<SensorSample>(256, true).unwrap();
        let status = c.finish(Duration::from_secs(60));
        assert!(status.is_some_and(|s| s.success()), "{}", c.show());
        expect_pattern(&sub);
        // And a Rust publisher can join the Python-made service.
        let mut p = b.publisher::<SensorSample>().unwrap();
        p.publish(&pattern(99)).unwrap();
        assert_eq!(sub.receive().unwrap(), Some(pattern(99)));
    }
}

fn control_pattern(k: u64) -> Control {
    let mut c = Control {
        dim: 2,
        status: (k % 2) as u32,
        cost: 100.0 + k as f64 * 0.25,
        goal: [k as f64, -(k as f64)],
        waypoint_index: 3 + k as u32,
        reserved: 0,
        waypoints_reached: 1000 + k,
        ..Control::default()
    };
    c.header.seq = k;
    c.header.t_valid_ns = 5_000 + k;
    c.header.t_pub_ns = 6_000 + k;
    c.trace.sensor_seq = 70 + k;
    c.trace.sensor_channel = 2;
    c.trace.t_meas_ns = 11 + k;
    c.trace.t_sensor_pub_ns = 12 + k;
    c.trace.t_ingest_in_ns = 13 + k;
    c.trace.t_ingest_out_ns = 14 + k;
    c.trace.t_filter_in_ns = 15 + k;
    c.trace.t_filter_out_ns = 16 + k;
    c.trace.t_control_in_ns = 17 + k;
    c.trace.t_control_out_ns = 18 + k;
    c.u = [0.5 + k as f64, -1.5, 2.25, -0.125];
    c
}

#[test]
fn rust_controls_reach_the_python_actuator_intact() {
    let Some(py) = python("rust_controls_reach_the_python_actuator_intact") else {
        return;
    };
    let prefix = TestPrefix::new();
    {
        let n = 5u64;
        let mut act = ChildGuard::spawn(&mut python_command(
            &py,
            "actuator.py",
            &[
                "--prefix".into(),
                prefix.0.clone(),
                "--instance".into(),
                "abi".into(),
                "--json".into(),
                "--count".into(),
                n.to_string(),
                "--idle".into(),
                "30".into(),
            ],
        ));
        let ready = act.wait_line(Stream::Stderr, Duration::from_secs(30), |l| {
            l.contains("listening on")
        });
        assert!(ready.is_some(), "{}", act.show());
        let b = bus(&prefix, "control");
        let mut p = b.publisher::<Control>().unwrap();
        for k in 0..n {
            p.publish(&control_pattern(k)).unwrap();
            // Latest-value channel: pace by the actuator's output.
            let line = act.wait_line(Stream::Stdout, Duration::from_secs(30), |l| {
                l.starts_with('{') && !l.contains("summary")
            });
            let line = line.unwrap_or_else(|| panic!("no control {k}\n{}", act.show()));
            let v: Value = serde_json::from_str(&line).unwrap();
            let e = control_pattern(k);
            assert_eq!(v["seq"], e.header.seq);
            assert_eq!(v["t_valid_ns"], e.header.t_valid_ns);
            assert_eq!(v["t_pub_ns"], e.header.t_pub_ns);
            let t = &v["trace"];
            assert_eq!(t["sensor_seq"], e.trace.sensor_seq);
            assert_eq!(t["sensor_channel"], e.trace.sensor_channel);
            assert_eq!(t["t_meas_ns"], e.trace.t_meas_ns);
            assert_eq!(t["t_sensor_pub_ns"], e.trace.t_sensor_pub_ns);
            assert_eq!(t["t_ingest_in_ns"], e.trace.t_ingest_in_ns);
            assert_eq!(t["t_ingest_out_ns"], e.trace.t_ingest_out_ns);
            assert_eq!(t["t_filter_in_ns"], e.trace.t_filter_in_ns);
            assert_eq!(t["t_filter_out_ns"], e.trace.t_filter_out_ns);
            assert_eq!(t["t_control_in_ns"], e.trace.t_control_in_ns);
            assert_eq!(t["t_control_out_ns"], e.trace.t_control_out_ns);
            assert_eq!(v["dim"], e.dim);
            assert_eq!(v["status"], e.status);
            assert_eq!(v["u"], serde_json::json!(e.u));
            assert_eq!(v["cost"], e.cost);
            assert_eq!(v["goal"], serde_json::json!(e.goal));
            assert_eq!(v["waypoint_index"], e.waypoint_index);
            assert_eq!(v["waypoints_reached"], e.waypoints_reached);
        }
        let status = act.finish(Duration::from_secs(30));
        assert!(status.is_some_and(|s| s.success()), "{}", act.show());
        let summary = act.stdout.last().cloned().unwrap_or_default();
        let v: Value = serde_json::from_str(&summary).expect("summary JSON");
        assert_eq!(v["summary"]["received"], n);
    }
}

/// The Python quick-start of `docs/sensor-abi.md`, as printed there, with
/// the test's prefix and a shorter loop.
fn doc_quick_start(prefix: &str, instance: &str, n: usize) -> String {
    let doc = std::fs::read_to_string(root().join("docs/sensor-abi.md")).unwrap();
    let start = doc.find("```python\n").expect("a python block") + "```python\n".len();
    let end = start + doc[start..].find("```").unwrap();
    let code = &doc[start..end];
    let settings = r#"PREFIX, INSTANCE, CHANNEL = "iox2_beliefbus_", "ship", 0"#;
    assert!(code.contains(settings), "quick start settings line changed");
    assert!(code.contains("range(1000)"), "quick start loop changed");
    code.replace(
        settings,
        &format!(r#"PREFIX, INSTANCE, CHANNEL = "{prefix}", "{instance}", 0"#),
    )
    .replace("range(1000)", &format!("range({n})"))
}

#[test]
fn the_documented_python_quick_start_works_as_printed() {
    let Some(py) = python("the_documented_python_quick_start_works_as_printed") else {
        return;
    };
    let prefix = TestPrefix::new();
    {
        let n = 30;
        let code = doc_quick_start(&prefix.0, "abi", n);
        let b = bus(&prefix, "ingest");
        let sub = b.subscriber_with::<SensorSample>(256, true).unwrap();
        let mut c = ChildGuard::spawn(std::process::Command::new(&py).args(["-c", &code]));
        let mut got = Vec::new();
        let _ = poll(Duration::from_secs(30), || {
            while let Some(s) = sub.receive().unwrap() {
                got.push(s);
            }
            (got.len() >= n).then_some(())
        });
        let status = c.finish(Duration::from_secs(30));
        assert!(status.is_some_and(|s| s.success()), "{}", c.show());
        assert_eq!(got.len(), n, "{}", c.show());
        let mut last_t = 0;
        for (k, s) in got.iter().enumerate() {
            let (x, y) = (3.0 + 0.01 * k as f64, 1.0f64);
            assert_eq!((s.seq, s.channel, s.dim, s.flags), (k as u64, 0, 2, 0));
            assert!((s.values[0] - x.hypot(y)).abs() < 1e-12);
            assert!((s.values[1] - y.atan2(x)).abs() < 1e-12);
            assert!(s.t_meas_ns > last_t && s.t_pub_ns >= s.t_meas_ns);
            // Stamped on this host's CLOCK_MONOTONIC: no later than now.
            assert!(s.t_pub_ns <= beliefbus::ipc::sensor_api::monotonic_now_ns());
            last_t = s.t_meas_ns;
        }
    }
}
