//! The example publishers of `tools/` on their own: the Rust and the Python
//! ship simulators publish numbered, timed range/bearing samples that agree
//! with the truth they publish alongside.

mod sensor_support;

use beliefbus::ipc::{Bus, BusConfig, SensorSample, Subscriber, Truth};
use sensor_support::*;
use std::process::Command;
use std::time::Duration;

const RATE: f64 = 200.0;
const N: usize = 60;

fn tool_args(prefix: &TestPrefix) -> Vec<String> {
    [
        "--prefix",
        &prefix.0,
        "--instance",
        "tools",
        "--channel",
        "3",
        "--rate",
        &RATE.to_string(),
        "--duration",
        &(N as f64 / RATE).to_string(),
        "--truth",
        "--wait-ingest",
        "30",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn drain<M: beliefbus::ipc::Message>(s: &Subscriber<M>, out: &mut Vec<M>) {
    while let Some(m) = s.receive().unwrap() {
        out.push(m);
    }
}

/// Run `cmd` against a sensor and a truth subscriber and check what arrives.
fn check_ship_publisher(prefix: &TestPrefix, mut cmd: Command) {
    let cfg = BusConfig {
        prefix: prefix.0.clone(),
        instance: "tools".into(),
    };
    let bus = Bus::open(&cfg, "ingest").unwrap();
    let sensor = bus.subscriber_with::<SensorSample>(256, true).unwrap();
    let truth = bus.subscriber_with::<Truth>(512, false).unwrap();
    let mut child = ChildGuard::spawn(&mut cmd);
    let (mut samples, mut truths) = (Vec::new(), Vec::new());
    let _ = poll(Duration::from_secs(60), || {
        drain(&sensor, &mut samples);
        drain(&truth, &mut truths);
        (samples.len() >= N && truths.len() >= N).then_some(())
    });
    let status = child.finish(Duration::from_secs(30));
    drain(&sensor, &mut samples);
    drain(&truth, &mut truths);
    assert!(status.is_some_and(|s| s.success()), "{}", child.show());
    assert_eq!(samples.len(), N, "{}", child.show());
    assert_eq!(truths.len(), N);

    let period_ns = 1e9 / RATE;
    let sigma = 0.03 / (1.0 / RATE).sqrt(); // the paper's sampled sensor noise
    let mut max_z: f64 = 0.0;
    for (k, (s, t)) in samples.iter().zip(&truths).enumerate() {
        assert_eq!((s.seq, s.channel, s.dim, s.flags), (k as u64, 3, 2, 0));
        assert_eq!(t.header.seq, s.seq);
        assert_eq!(t.header.t_valid_ns, s.t_meas_ns);
        assert_eq!((t.dim, t.obs_dim), (4, 2));
        assert_eq!(&t.y[..2], &s.values[..2], "truth carries the measurement");
        assert!(s.t_pub_ns >= s.t_meas_ns);
        if k > 0 {
            assert!(s.t_meas_ns > samples[k - 1].t_meas_ns);
        }
        // The measurement is the true range/bearing plus noise of σ.
        let (x1, x2) = (t.x[0], t.x[1]);
        let z_r = (s.values[0] - x1.hypot(x2)) / sigma;
        let mut db = s.values[1] - x2.atan2(x1);
        db = db.sin().atan2(db.cos());
        max_z = max_z.max(z_r.abs()).max((db / sigma).abs());
    }
    // 120 standard normals: |z| > 5 has probability ~7e-5.
    assert!(max_z < 5.0, "max |z| = {max_z}");
    // Paced on an absolute schedule: a late sample is followed by a quick
    // one, but the whole run never runs ahead of the rate.
    let span = (samples[N - 1].t_meas_ns - samples[0].t_meas_ns) as f64;
    assert!(span >= 0.9 * (N - 1) as f64 * period_ns, "span {span} ns");
}

#[test]
fn the_rust_example_sensor_publishes_the_ship() {
    let prefix = TestPrefix::new();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_beliefbus-example-sensor"));
    cmd.args(tool_args(&prefix));
    check_ship_publisher(&prefix, cmd);
}

#[test]
fn the_python_sensor_publisher_publishes_the_ship() {
    let Some(py) = python("the_python_sensor_publisher_publishes_the_ship") else {
        return;
    };
    let prefix = TestPrefix::new();
    let cmd = python_command(&py, "sensor_publisher.py", &tool_args(&prefix));
    check_ship_publisher(&prefix, cmd);
}
