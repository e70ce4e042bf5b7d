//! A rogue publisher on the internal observation channel: ingest
//! rejects absurd measurement times from sensors, but anything that can
//! open the `obs` service can bypass it. The filter stage must reject such
//! observations before `predict` (counted as `time_out_of_range`), never
//! crash or stall, and keep filtering the good ones around them.
//!
//! The real filter stage runs on a thread of this process on its own
//! iceoryx2 prefix; this thread plays ingest and the rogue. Waits are
//! liveness guards only, never timing assertions.

use beliefbus::ipc::{cleanup, Belief, Bus, Observation, StageKind, StageStats};
use beliefbus::model::SdeModel;
use beliefbus::pipeline::config;
use beliefbus::rt::clock::now_ns;
use beliefbus::rt::MonotonicClock;
use beliefbus::scenario::Plant;
use beliefbus::stage::filter::Reason;
use beliefbus::stage::plant::Simulator;
use beliefbus::stage::{run_stage, StageIdentity};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const PATIENCE: Duration = Duration::from_secs(120);

/// Removes the prefix's resources at the end, also when an assertion fails.
struct Teardown(String);
impl Drop for Teardown {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.0);
    }
}

fn run(backend: &str) {
    let prefix = cleanup::run_prefix();
    let _t = Teardown(prefix.clone());
    let c = config::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
        &[
            format!("run.prefix=\"{prefix}\""),
            format!("filter.backend=\"{backend}\""),
            "filter.pf.particles=300".into(),
            "run.stats_period_s=0.1".into(),
        ],
    )
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let filter = {
        let (c, stop) = (c.clone(), stop.clone());
        std::thread::spawn(move || {
            run_stage(
                &c.bus(),
                &c,
                StageIdentity::plain(StageKind::Filter),
                &MonotonicClock,
                &stop,
            )
        })
    };
    let bus = Bus::open(&c.bus(), "rogue").unwrap();
    let mut obs = bus.publisher::<Observation>().unwrap();
    let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let deadline = Instant::now() + PATIENCE;
    while stats.receive().unwrap().is_none() {
        assert!(Instant::now() < deadline, "the filter never reported");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(150)); // let it connect to us

    let model = c.model().unwrap();
    let mut sim = Simulator::new(model.clone(), &c.plant.initial_state, 9, 1e-3);
    let mut o = Observation {
        dim: model.dims().obs as u32,
        mask: 0b11,
        ..Observation::default()
    };
    let mut seq = 0u64;
    let mut send = |t_valid: u64, y: &[f64]| {
        let now = now_ns();
        o.y[..2].copy_from_slice(y);
        o.header.seq = seq;
        o.header.t_valid_ns = t_valid;
        o.header.t_pub_ns = now;
        o.trace.sensor_seq = seq;
        o.trace.t_meas_ns = t_valid;
        o.trace.t_sensor_pub_ns = now;
        o.trace.t_ingest_in_ns = now;
        o.trace.t_ingest_out_ns = now;
        obs.publish(&o).unwrap();
        seq += 1;
    };
    // One good observation is filtered: wait for its belief.
    let expect = |t_valid: u64| {
        let deadline = Instant::now() + PATIENCE;
        loop {
            if let Some(b) = beliefs.receive().unwrap() {
                assert_eq!(b.header.t_valid_ns, t_valid, "a rogue sample was filtered");
                assert!(b.mean[..4].iter().all(|v| v.is_finite()));
                return;
            }
            assert!(Instant::now() < deadline, "no belief for t={t_valid}");
            std::thread::sleep(Duration::from_micros(200));
        }
    };
    let mut y = [0.0; 2];
    let mut good = 0u64;
    let mut rogue = 0u64;
    // A rogue first sample would set an absurd time origin (1 ns after
    // boot): every later observation would then be a prediction over the
    // machine's uptime.
    send(1, &[0.0, 0.0]);
    rogue += 1;
    for round in 0..3 {
        for _ in 0..20 {
            sim.advance(0.01);
            sim.measure(&mut y);
            std::thread::sleep(Duration::from_millis(2));
            let t = now_ns();
            send(t, &y);
            expect(t);
            good += 1;
        }
        // Absurd times between good ones: the end of time, eleven days
        // ahead, unset.
        let absurd = [u64::MAX, now_ns() + 1_000_000_000_000_000, 0];
        send(absurd[round], &y);
        rogue += 1;
    }
    // Nothing more comes out for the rogue samples.
    std::thread::sleep(Duration::from_millis(100));
    assert!(beliefs.receive().unwrap().is_none());
    // The filter accounted for each of them before stopping.
    let deadline = Instant::now() + PATIENCE;
    let mut last: Option<StageStats> = None;
    while last
        .as_ref()
        .is_none_or(|s| s.processed + s.rejected < good + rogue)
    {
        assert!(Instant::now() < deadline, "{last:?}");
        while let Some(s) = stats.receive().unwrap() {
            last = Some(s);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    stop.store(true, Ordering::Relaxed);
    let fin = filter.join().unwrap().unwrap();
    drop((obs, beliefs, stats, bus));
    assert_eq!(fin.processed, good, "{backend}");
    assert_eq!(fin.rejected, rogue, "{backend}");
    assert_eq!(
        fin.rejected_by_reason[Reason::TimeRange as usize],
        rogue,
        "{backend}: {:?}",
        fin.rejected_by_reason
    );
    assert_eq!(fin.dropped, 0, "{backend}");
    let _ = cleanup::remove_prefix(&prefix);
    assert!(cleanup::resources(&prefix).is_empty());
}

#[test]
fn absurd_measurement_times_on_the_internal_channel_are_rejected_and_counted() {
    for backend in ["ekf", "pf"] {
        run(backend);
    }
}

#[test]
fn the_guard_bounds_both_sides() {
    use beliefbus::stage::filter::{time_out_of_range, MAX_EPOCH_AGE_NS};
    let now = 1_000_000_000_000u64;
    let ahead = 500_000_000;
    assert!(!time_out_of_range(now, now, ahead, true));
    assert!(!time_out_of_range(now + ahead, now, ahead, false));
    assert!(time_out_of_range(now + ahead + 1, now, ahead, false));
    assert!(time_out_of_range(u64::MAX, now, ahead, false));
    assert!(time_out_of_range(0, now, ahead, false));
    // Old samples: only the time origin is bounded (later ones are checked
    // against the filter's own time: time_backwards).
    assert!(!time_out_of_range(now - MAX_EPOCH_AGE_NS, now, ahead, true));
    assert!(time_out_of_range(
        now - MAX_EPOCH_AGE_NS - 1,
        now,
        ahead,
        true
    ));
    assert!(!time_out_of_range(1, now, ahead, false));
}
