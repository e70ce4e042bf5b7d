//! The sensor and actuator API against a real bus on a private prefix.

use super::*;
use crate::cleanup;
use crate::messages::Control;
use crate::ports::Subscriber;

/// A fresh prefix, removed when dropped.
struct Prefix(String);
impl Prefix {
    fn new() -> Self {
        Self(cleanup::run_prefix())
    }
}
impl Drop for Prefix {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.0);
    }
}

fn ingest(p: &Prefix) -> (Bus, Subscriber<SensorSample>) {
    let cfg = BusConfig {
        prefix: p.0.clone(),
        instance: "t".into(),
    };
    let bus = Bus::open(&cfg, "ingest").unwrap();
    let sub = bus.subscriber::<SensorSample>().unwrap();
    (bus, sub)
}

#[test]
fn samples_arrive_numbered_per_channel_with_every_field() {
    let p = Prefix::new();
    let (_bus, sub) = ingest(&p);
    let mut s = SensorPublisher::connect("t", &p.0).unwrap();
    assert_eq!(s.subscribers(), 1);
    let t0 = monotonic_now_ns();
    assert_eq!(s.publish(3, t0, &[1.5, -2.0]).unwrap(), 0);
    assert_eq!(s.publish(9, t0, &[7.0]).unwrap(), 0);
    assert_eq!(
        s.publish_with_std(3, t0 + 1, &[1.0, 2.0], &[0.5, 0.25])
            .unwrap(),
        1
    );
    assert_eq!(s.next_seq(3), 2);
    assert_eq!(s.next_seq(9), 1);
    assert_eq!(s.next_seq(4), 0);

    let a = sub.receive().unwrap().unwrap();
    assert_eq!((a.channel, a.seq, a.dim, a.flags), (3, 0, 2, 0));
    assert_eq!(a.t_meas_ns, t0);
    assert!(a.t_pub_ns >= t0);
    assert_eq!(&a.values[..3], &[1.5, -2.0, 0.0]);
    assert_eq!(a.reserved, [0; 8]);
    let b = sub.receive().unwrap().unwrap();
    assert_eq!((b.channel, b.seq, b.dim), (9, 0, 1));
    let c = sub.receive().unwrap().unwrap();
    assert_eq!((c.channel, c.seq, c.flags), (3, 1, 1));
    assert!(c.has_noise_std());
    assert_eq!(&c.noise_std[..2], &[0.5, 0.25]);
    assert!(sub.receive().unwrap().is_none());
}

#[test]
fn bad_input_is_a_typed_error_and_nothing_is_sent() {
    let p = Prefix::new();
    let (_bus, sub) = ingest(&p);
    let mut s = SensorPublisher::connect("t", &p.0).unwrap();
    let t = monotonic_now_ns();
    let e = |r: Result<u64, SensorError>| r.unwrap_err();
    assert_eq!(e(s.publish(0, t, &[])), SensorError::Dimension { got: 0 });
    assert_eq!(
        e(s.publish(0, t, &[0.0; 9])),
        SensorError::Dimension { got: 9 }
    );
    assert!(matches!(
        e(s.publish(0, t, &[1.0, f64::INFINITY])),
        SensorError::NonFinite { index: 1, .. }
    ));
    assert_eq!(
        e(s.publish_with_std(0, t, &[1.0, 2.0], &[1.0])),
        SensorError::NoiseLength { values: 2, std: 1 }
    );
    assert!(matches!(
        e(s.publish_with_std(0, t, &[1.0, 2.0], &[1.0, 0.0])),
        SensorError::BadNoise { index: 1, .. }
    ));
    assert!(matches!(
        e(s.publish_with_std(0, t, &[1.0], &[f64::NAN])),
        SensorError::BadNoise { index: 0, .. }
    ));
    assert_eq!(e(s.publish(0, 0, &[1.0])), SensorError::ZeroTime);
    assert!(matches!(
        e(s.publish(0, t + 60_000_000_000, &[1.0])),
        SensorError::FutureTime { .. }
    ));
    assert!(sub.receive().unwrap().is_none(), "nothing was sent");
    assert_eq!(s.sent(), 0);
    // Time may repeat but not go back; a refused sample uses no seq.
    assert_eq!(s.publish(0, t, &[1.0]).unwrap(), 0);
    assert_eq!(s.publish(0, t, &[1.0]).unwrap(), 1);
    assert_eq!(
        e(s.publish(0, t - 1, &[1.0])),
        SensorError::TimeBackwards {
            channel: 0,
            t_ns: t - 1,
            last_ns: t
        }
    );
    // Another channel has its own clock history.
    assert_eq!(s.publish(1, t - 1, &[1.0]).unwrap(), 0);
    assert_eq!(s.publish(0, t + 1, &[1.0]).unwrap(), 2);
    assert_eq!(s.sent(), 4);
}

#[test]
fn publish_sample_sends_faults_unchanged() {
    let p = Prefix::new();
    let (_bus, sub) = ingest(&p);
    let mut s = SensorPublisher::connect("t", &p.0).unwrap();
    let mut bad = SensorSample::new(5, 42, 7, &[f64::NAN, f64::NEG_INFINITY]);
    bad.reserved0 = 0xdead;
    s.publish_sample(&bad).unwrap();
    let got = sub.receive().unwrap().unwrap();
    assert!(got.values[0].is_nan() && got.values[1] == f64::NEG_INFINITY);
    assert_eq!((got.channel, got.seq, got.t_meas_ns), (5, 42, 7));
    assert_eq!(got.reserved0, 0xdead);
    assert!(got.t_pub_ns > 0, "publish time stamped");
}

#[test]
fn oversized_values_are_never_silently_truncated() {
    let s = SensorSample::new(0, 0, 1, &[1.0; 9]);
    assert_eq!(s.dim, 9, "dim keeps the true length so ingest rejects it");
    assert_eq!(s.values, [1.0; SENSOR_MAX_DIM]);
}

#[test]
fn wait_for_subscribers_sees_a_late_ingest() {
    let p = Prefix::new();
    let s = SensorPublisher::connect("t", &p.0).unwrap();
    assert_eq!(s.subscribers(), 0);
    assert!(!s.wait_for_subscribers(1, Duration::from_millis(10)));
    let (_bus, _sub) = ingest(&p);
    assert!(s.wait_for_subscribers(1, Duration::from_secs(5)));
}

#[test]
fn the_actuator_wakes_for_each_control_and_sees_the_newest() {
    let p = Prefix::new();
    let cfg = BusConfig {
        prefix: p.0.clone(),
        instance: "t".into(),
    };
    let mut act = ControlSubscriber::connect("t", &p.0).unwrap();
    assert!(act.wait(Duration::from_millis(5)).unwrap().is_none());
    let (ack_tx, ack_rx) = std::sync::mpsc::channel::<()>();
    let producer = std::thread::spawn(move || {
        let bus = Bus::open(&cfg, "control").unwrap();
        let mut pubr = bus.publisher::<Control>().unwrap();
        // Paced: the next control only after the actuator has read one.
        for k in 0..3u64 {
            let mut c = Control {
                dim: 2,
                ..Control::default()
            };
            c.header.seq = k;
            c.u[0] = k as f64;
            pubr.publish(&c).unwrap();
            ack_rx.recv().unwrap();
        }
        // A burst: the actuator only needs the newest.
        for k in 3..10u64 {
            let mut c = Control::default();
            c.header.seq = k;
            pubr.publish(&c).unwrap();
        }
        // Keep the publisher alive until the actuator is done.
        let _ = ack_rx.recv();
    });
    let mut seqs = Vec::new();
    while let Some(c) = act.wait(Duration::from_secs(10)).unwrap() {
        seqs.push(c.header.seq);
        if c.header.seq < 3 {
            assert_eq!(c.u[0], c.header.seq as f64);
            ack_tx.send(()).unwrap();
        }
        if c.header.seq == 9 {
            break;
        }
    }
    ack_tx.send(()).unwrap();
    producer.join().unwrap();
    assert_eq!(&seqs[..3], &[0, 1, 2], "every paced control woke it");
    assert_eq!(*seqs.last().unwrap(), 9);
    assert!(seqs.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(act.received(), seqs.len() as u64);
}
