//! Behaviour of the bus, ports and wake-ups, each test under its own prefix.

use super::*;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A bus config under a fresh prefix, removed when dropped.
struct TestBus {
    cfg: BusConfig,
}

impl TestBus {
    fn new() -> Self {
        Self {
            cfg: BusConfig {
                prefix: cleanup::run_prefix(),
                instance: "test".into(),
            },
        }
    }
    fn open(&self, node: &str) -> Bus {
        Bus::open(&self.cfg, node).unwrap()
    }
}

impl Drop for TestBus {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.cfg.prefix);
    }
}

fn belief(seq: u64) -> Belief {
    let mut b = Belief::default();
    b.header.seq = seq;
    b
}

#[test]
fn latest_value_channel_keeps_only_the_newest() {
    let tb = TestBus::new();
    let bus = tb.open("t");
    let mut p = bus.publisher::<Belief>().unwrap();
    let s = bus.subscriber::<Belief>().unwrap();
    for i in 0..5 {
        p.publish(&belief(i)).unwrap();
    }
    let (m, skipped) = s.latest().unwrap();
    assert_eq!(m.unwrap().header.seq, 4);
    assert_eq!(skipped, 0, "a buffer of 1 holds only the newest");
    assert!(s.receive().unwrap().is_none());
}

#[test]
fn a_late_subscriber_gets_the_last_belief_from_history() {
    let tb = TestBus::new();
    let bus = tb.open("t");
    let mut p = bus.publisher::<Belief>().unwrap();
    p.publish(&belief(1)).unwrap();
    p.publish(&belief(2)).unwrap();
    let s = bus.subscriber::<Belief>().unwrap();
    // History is delivered when the publisher next updates its connections.
    p.publish(&belief(3)).unwrap();
    let (m, _) = s.latest().unwrap();
    assert_eq!(m.unwrap().header.seq, 3);
}

#[test]
fn a_full_obs_queue_drops_the_oldest_and_never_blocks() {
    let tb = TestBus::new();
    let bus = tb.open("t");
    let mut p = bus.publisher::<Observation>().unwrap();
    let s = bus.subscriber::<Observation>().unwrap();
    for i in 0..40u64 {
        let mut o = Observation::default();
        o.header.seq = i;
        p.publish(&o).unwrap();
    }
    let mut got = Vec::new();
    while let Some(o) = s.receive().unwrap() {
        got.push(o.header.seq);
    }
    let n = Observation::QOS.default_buffer as u64;
    assert_eq!(got, (40 - n..40).collect::<Vec<_>>());
}

#[test]
fn a_monitor_with_a_large_buffer_sees_every_message() {
    let tb = TestBus::new();
    let bus = tb.open("t");
    let mut p = bus.publisher::<Belief>().unwrap();
    let stage = bus.subscriber::<Belief>().unwrap();
    let monitor = bus.subscriber_with::<Belief>(200, false).unwrap();
    for i in 0..150 {
        p.publish(&belief(i)).unwrap();
    }
    let mut n = 0;
    while monitor.receive().unwrap().is_some() {
        n += 1;
    }
    assert_eq!(n, 150);
    assert_eq!(stage.latest().unwrap().0.unwrap().header.seq, 149);
}

#[test]
fn prefixes_isolate_pipelines() {
    let a = TestBus::new();
    let b = TestBus::new();
    let bus_a = a.open("a");
    let bus_b = b.open("b");
    let mut p = bus_a.publisher::<Control>().unwrap();
    let s = bus_b.subscriber::<Control>().unwrap();
    p.publish(&Control::default()).unwrap();
    assert!(s.receive().unwrap().is_none());
}

#[test]
fn invalid_names_are_typed_errors() {
    let bad = BusConfig {
        prefix: "has space".into(),
        instance: "x".into(),
    };
    assert!(matches!(
        Bus::open(&bad, "n"),
        Err(IpcError::InvalidName { what: "prefix", .. })
    ));
    let bad = BusConfig {
        prefix: cleanup::run_prefix(),
        instance: "a/b".into(),
    };
    assert!(matches!(
        bad.validate(),
        Err(IpcError::InvalidName {
            what: "instance",
            ..
        })
    ));
}

fn wake_round_trip(mode: WakeMode) {
    let tb = TestBus::new();
    let cfg = tb.cfg.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let received = Arc::new(AtomicU64::new(0));
    let ticks = Arc::new(AtomicU64::new(0));
    let ready = Arc::new(AtomicBool::new(false));
    let (stop2, received2, ticks2, ready2) =
        (stop.clone(), received.clone(), ticks.clone(), ready.clone());
    let consumer = std::thread::spawn(move || {
        let bus = Bus::open(&cfg, "consumer").unwrap();
        let sub = bus.subscriber::<Observation>().unwrap();
        ready2.store(true, Ordering::SeqCst);
        run_loop(&[&sub], mode, Duration::from_millis(20), &stop2, |w| {
            match w {
                Wake::Data => {
                    while let Some(o) = sub.receive().unwrap() {
                        received2.fetch_add(1, Ordering::SeqCst);
                        if o.header.seq == 99 {
                            return ControlFlow::Break(());
                        }
                    }
                }
                Wake::Tick => {
                    ticks2.fetch_add(1, Ordering::SeqCst);
                }
            }
            ControlFlow::Continue(())
        })
        .unwrap();
    });
    while !ready.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(1));
    }
    let bus = tb.open("producer");
    let mut p = bus.publisher::<Observation>().unwrap();
    for i in 0..100u64 {
        let mut o = Observation::default();
        o.header.seq = i;
        p.publish(&o).unwrap();
        // Lockstep: the next message only after the loop received this one
        // (so the 8-deep queue cannot overflow however slow the machine).
        while received.load(Ordering::SeqCst) <= i {
            std::thread::sleep(Duration::from_micros(50));
        }
        if i == 50 {
            std::thread::sleep(Duration::from_millis(60)); // let a tick pass
        }
    }
    consumer.join().unwrap();
    assert_eq!(received.load(Ordering::SeqCst), 100);
    assert!(ticks.load(Ordering::SeqCst) >= 1);
    stop.store(true, Ordering::SeqCst);
}

#[test]
fn event_mode_wakes_the_loop_for_every_message() {
    wake_round_trip(WakeMode::Event);
}

#[test]
fn spin_then_block_mode_wakes_the_loop_for_every_message() {
    wake_round_trip(WakeMode::SpinThenBlock {
        spin: Duration::from_micros(50),
    });
}

#[test]
fn the_stop_flag_ends_an_idle_loop() {
    let tb = TestBus::new();
    let bus = tb.open("t");
    let sub = bus.subscriber::<Belief>().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let setter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(30));
        s2.store(true, Ordering::SeqCst);
    });
    let mut data_wakes = 0;
    run_loop(
        &[&sub],
        WakeMode::Event,
        Duration::from_secs(10),
        &stop,
        |w| {
            if w == Wake::Data {
                data_wakes += 1;
            }
            ControlFlow::Continue(())
        },
    )
    .unwrap();
    setter.join().unwrap();
    assert_eq!(data_wakes, 0);
}

#[test]
fn stage_and_hop_names_are_the_report_keys_and_parse_back() {
    use strum::VariantNames;
    let names: Vec<&str> = StageKind::ALL.iter().map(|s| s.name()).collect();
    assert_eq!(names, StageKind::VARIANTS);
    assert_eq!(names, ["ingest", "filter", "control", "refine", "plant"]);
    for s in StageKind::ALL {
        assert_eq!(StageKind::from_name(s.name()), Some(s));
    }
    assert_eq!(StageKind::from_name("Filter"), None);
    assert_eq!(StageKind::from_name("sensor"), None);
    let keys: Vec<&str> = Hop::ALL.iter().map(|h| h.key()).collect();
    assert_eq!(
        keys,
        [
            "sensor->ingest",
            "ingest->filter",
            "filter->control",
            "sensor->belief",
            "sensor->control"
        ]
    );
    let rejects: Vec<&str> = [
        ControlReject::Dimension,
        ControlReject::NonFinite,
        ControlReject::Limit,
    ]
    .iter()
    .map(|r| r.name())
    .collect();
    assert_eq!(rejects, ControlReject::VARIANTS);
    assert_eq!(
        rejects,
        ["control_dimension", "control_non_finite", "control_limit"]
    );
}
