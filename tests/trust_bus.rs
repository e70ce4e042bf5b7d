//! A bus that distrusts its publishers (docs/security.md): a same-user
//! process that opens the run's services can publish on them. These tests
//! play that rogue against the real stage loops, each run on a thread of
//! this process under its own iceoryx2 prefix. Waits are liveness guards
//! only, never timing assertions.

use beliefbus::ipc::{cleanup, Bus, Control, ControlLimits, StageKind, StageStats, Truth};
use beliefbus::pipeline::config;
use beliefbus::rt::clock::now_ns;
use beliefbus::rt::MonotonicClock;
use beliefbus::stage::plant::Reason;
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

fn default_config(prefix: &str, sets: &[&str]) -> config::PipelineConfig {
    let mut all = vec![
        format!("run.prefix=\"{prefix}\""),
        "run.stats_period_s=0.1".into(),
    ];
    all.extend(sets.iter().map(|s| s.to_string()));
    config::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
        &all,
    )
    .unwrap()
}

/// Waits until `f` holds for the newest stats of `kind` (returns them).
fn stats_until(
    sub: &beliefbus::ipc::Subscriber<StageStats>,
    kind: StageKind,
    last: &mut Option<StageStats>,
    f: impl Fn(&StageStats) -> bool,
) -> StageStats {
    let deadline = Instant::now() + PATIENCE;
    loop {
        while let Some(s) = sub.receive().unwrap() {
            if s.stage == kind as u32 {
                *last = Some(s);
            }
        }
        if let Some(s) = last.as_ref().filter(|s| f(s)) {
            return *s;
        }
        assert!(Instant::now() < deadline, "{kind:?}: {last:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Rogue controls — far outside the limits (the finding: u = ±50 with a
/// limit of 3), NaN, of the wrong dimension — are counted by reason and
/// never applied; the plant holds the last good control and its state
/// stays finite.
#[test]
fn the_plant_applies_only_finite_controls_inside_the_limits() {
    let prefix = cleanup::run_prefix();
    let _t = Teardown(prefix.clone());
    let c = default_config(&prefix, &[]);
    let limits = c.control_limits().unwrap();
    assert_eq!(limits, ControlLimits::new(&[-3.0, -3.0], &[3.0, 3.0]));
    let stop = Arc::new(AtomicBool::new(false));
    let plant = {
        let (c, stop) = (c.clone(), stop.clone());
        std::thread::spawn(move || {
            run_stage(
                &c.bus(),
                &c,
                StageIdentity::plain(StageKind::Plant),
                &MonotonicClock,
                &stop,
            )
        })
    };
    let bus = Bus::open(&c.bus(), "controller").unwrap();
    let mut ctl = bus.publisher::<Control>().unwrap();
    let truth = bus.subscriber_with::<Truth>(512, false).unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let mut last = None;
    stats_until(&stats, StageKind::Plant, &mut last, |_| true);
    std::thread::sleep(Duration::from_millis(150)); // let it connect to us

    let mut seq = 0;
    let mut send = |dim: u32, u: [f64; 2]| {
        let mut m = Control {
            dim,
            ..Control::default()
        };
        m.u[..2].copy_from_slice(&u);
        m.header.seq = seq;
        m.header.t_pub_ns = now_ns();
        seq += 1;
        ctl.publish(&m).unwrap();
        // One control per plant tick (10 ms), so none is overwritten.
        std::thread::sleep(Duration::from_millis(25));
    };
    let good = [1.5, -2.0];
    send(2, good);
    let rogue: [(u32, [f64; 2], Reason); 6] = [
        (2, [50.0, 0.0], Reason::Limit),
        (2, [0.0, -50.0], Reason::Limit),
        (2, [f64::NAN, 0.0], Reason::NonFinite),
        (2, [0.0, f64::INFINITY], Reason::NonFinite),
        (3, [0.1, 0.1], Reason::Dimension),
        (0, [0.0, 0.0], Reason::Dimension),
    ];
    for (dim, u, _) in rogue {
        send(dim, u);
    }
    let s = stats_until(&stats, StageKind::Plant, &mut last, |s| {
        s.controls_received + s.rejected > rogue.len() as u64
    });
    // Every truth the plant published: the good control or none, never a
    // rogue one, and a finite state.
    let mut n = 0;
    while let Some(t) = truth.receive().unwrap() {
        n += 1;
        let u = &t.u[..2];
        assert!(u == [0.0, 0.0] || u == good, "applied {u:?}");
        assert!(t.x[..4].iter().all(|v| v.is_finite()), "{:?}", t.x);
    }
    assert!(n > 0);
    stop.store(true, Ordering::Relaxed);
    let fin = plant.join().unwrap().unwrap();
    drop((ctl, truth, stats, bus));
    assert_eq!(s.controls_received, 1, "{s:?}");
    assert_eq!(fin.rejected, rogue.len() as u64, "{fin:?}");
    for r in Reason::ALL {
        let want = rogue.iter().filter(|(_, _, x)| *x == r).count() as u64;
        assert_eq!(fin.rejected_by_reason[r as usize], want, "{}", r.name());
    }
    let _ = cleanup::remove_prefix(&prefix);
    assert!(cleanup::resources(&prefix).is_empty());
}

fn spawn_stage(
    c: &config::PipelineConfig,
    kind: StageKind,
    stop: &Arc<AtomicBool>,
) -> std::thread::JoinHandle<Result<StageStats, beliefbus::stage::StageError>> {
    let (c, stop) = (c.clone(), stop.clone());
    std::thread::spawn(move || {
        run_stage(
            &c.bus(),
            &c,
            StageIdentity::plain(kind),
            &MonotonicClock,
            &stop,
        )
    })
}

/// A second publisher on the sensor channel — one sample numbered 2⁶², then
/// samples claiming σ = 1e-3 — is refused as `foreign_publisher` while the
/// channel's own publisher stays connected, and every genuine sample is
/// accepted (the finding: 375 genuine samples rejected as `duplicate`).
#[test]
fn ingest_accepts_every_genuine_sample_and_refuses_a_second_publisher() {
    use beliefbus::ipc::{Observation, SensorSample};
    use beliefbus::stage::ingest::Reason;
    let prefix = cleanup::run_prefix();
    let _t = Teardown(prefix.clone());
    let c = default_config(&prefix, &[]);
    let stop = Arc::new(AtomicBool::new(false));
    let ingest = spawn_stage(&c, StageKind::Ingest, &stop);
    let bus = Bus::open(&c.bus(), "sensor").unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let obs = bus.subscriber_with::<Observation>(32, false).unwrap();
    let mut last = None;
    stats_until(&stats, StageKind::Ingest, &mut last, |_| true);
    let mut genuine = bus.publisher::<SensorSample>().unwrap();
    let rogue_bus = Bus::open(&c.bus(), "rogue").unwrap();
    let mut rogue = rogue_bus.publisher::<SensorSample>().unwrap();
    std::thread::sleep(Duration::from_millis(150)); // let ingest connect
    let n = 60u64;
    let mut forwarded = 0;
    for k in 0..n {
        let t = now_ns();
        genuine
            .publish(&SensorSample::new(0, k, t, &[5.0, 0.1]))
            .unwrap();
        if k == 5 {
            rogue
                .publish(&SensorSample::new(0, 1 << 62, t + 1, &[5.0, 0.1]))
                .unwrap();
        }
        if k % 10 == 7 {
            let s = SensorSample::new(0, k + 1, t + 1, &[50.0, 3.0]).with_noise_std(&[1e-3, 1e-3]);
            rogue.publish(&s).unwrap();
        }
        std::thread::sleep(Duration::from_millis(12));
        while let Some(o) = obs.receive().unwrap() {
            assert_eq!(o.y[..2], [5.0, 0.1], "a rogue sample was forwarded");
            forwarded += 1;
        }
    }
    let rogue_sent = 1 + (0..n).filter(|k| k % 10 == 7).count() as u64;
    let s = stats_until(&stats, StageKind::Ingest, &mut last, |s| {
        s.processed + s.rejected >= n + rogue_sent
    });
    stop.store(true, Ordering::Relaxed);
    let fin = ingest.join().unwrap().unwrap();
    while let Some(o) = obs.receive().unwrap() {
        assert_eq!(o.y[..2], [5.0, 0.1]);
        forwarded += 1;
    }
    drop((genuine, rogue, obs, stats, bus, rogue_bus));
    assert_eq!(s.processed, n, "{s:?}");
    assert_eq!(forwarded, n);
    assert_eq!(fin.rejected, rogue_sent, "{:?}", fin.rejected_by_reason);
    assert_eq!(
        fin.rejected_by_reason[Reason::ForeignPublisher as usize],
        rogue_sent
    );
    assert_eq!(fin.rejected_by_reason[Reason::Duplicate as usize], 0);
    let _ = cleanup::remove_prefix(&prefix);
    assert!(cleanup::resources(&prefix).is_empty());
}

/// Observations published by anyone but the run's ingest (the finding: 10
/// rogue observations were filtered and the books went to −999 999 646)
/// are refused as `foreign_publisher`, move no estimate and stay out of
/// the observation books.
#[test]
fn the_filter_refuses_observations_not_from_its_ingest() {
    use beliefbus::ipc::{Belief, Observation};
    use beliefbus::stage::filter::Reason;
    let prefix = cleanup::run_prefix();
    let _t = Teardown(prefix.clone());
    let c = default_config(&prefix, &["filter.backend=\"ekf\""]);
    let stop = Arc::new(AtomicBool::new(false));
    let filter = spawn_stage(&c, StageKind::Filter, &stop);
    let bus = Bus::open(&c.bus(), "ingest").unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
    let mut last = None;
    stats_until(&stats, StageKind::Filter, &mut last, |_| true);
    let mut ingest = bus.publisher::<Observation>().unwrap();
    let rogue_bus = Bus::open(&c.bus(), "rogue").unwrap();
    let mut rogue = rogue_bus.publisher::<Observation>().unwrap();
    std::thread::sleep(Duration::from_millis(150));
    let mut o = Observation {
        dim: 2,
        mask: 0b11,
        ..Observation::default()
    };
    let n = 30u64;
    let mut rogue_sent = 0;
    let mut n_beliefs = 0;
    for k in 0..n {
        let t = now_ns();
        o.y[..2].copy_from_slice(&[3.0, 0.0]);
        o.header.seq = k;
        o.header.t_valid_ns = t;
        o.header.t_pub_ns = t;
        ingest.publish(&o).unwrap();
        std::thread::sleep(Duration::from_millis(5));
        if k % 3 == 1 {
            let mut r = o;
            r.y[..2].copy_from_slice(&[1e6, 3.0]);
            r.header.seq = 1_000_000_000 + k;
            r.header.t_valid_ns = now_ns();
            rogue.publish(&r).unwrap();
            rogue_sent += 1;
        }
        std::thread::sleep(Duration::from_millis(5));
        while let Some(b) = beliefs.receive().unwrap() {
            assert!(
                b.mean[..4].iter().all(|v| v.is_finite() && v.abs() < 100.0),
                "{:?}",
                b.mean
            );
            n_beliefs += 1;
        }
    }
    let s = stats_until(&stats, StageKind::Filter, &mut last, |s| {
        s.processed + s.rejected >= n + rogue_sent
    });
    stop.store(true, Ordering::Relaxed);
    let fin = filter.join().unwrap().unwrap();
    while let Some(b) = beliefs.receive().unwrap() {
        assert!(
            b.mean[..4].iter().all(|v| v.is_finite() && v.abs() < 100.0),
            "{:?}",
            b.mean
        );
        n_beliefs += 1;
    }
    drop((ingest, rogue, beliefs, stats, bus, rogue_bus));
    assert_eq!(s.processed, n, "{s:?}");
    assert_eq!(n_beliefs, n);
    assert_eq!(fin.rejected_by_reason[Reason::Foreign as usize], rogue_sent);
    let _ = cleanup::remove_prefix(&prefix);
    assert!(cleanup::resources(&prefix).is_empty());
}

/// A second controller inside the limits is still not the run's
/// controller: its controls are refused as `foreign_publisher`.
#[test]
fn the_plant_refuses_controls_from_a_second_controller() {
    let prefix = cleanup::run_prefix();
    let _t = Teardown(prefix.clone());
    let c = default_config(&prefix, &[]);
    let stop = Arc::new(AtomicBool::new(false));
    let plant = spawn_stage(&c, StageKind::Plant, &stop);
    let bus = Bus::open(&c.bus(), "controller").unwrap();
    let stats = bus.subscriber_with::<StageStats>(64, false).unwrap();
    let truth = bus.subscriber_with::<Truth>(512, false).unwrap();
    let mut last = None;
    stats_until(&stats, StageKind::Plant, &mut last, |_| true);
    let mut ctl = bus.publisher::<Control>().unwrap();
    let rogue_bus = Bus::open(&c.bus(), "rogue").unwrap();
    let mut rogue = rogue_bus.publisher::<Control>().unwrap();
    std::thread::sleep(Duration::from_millis(150));
    let mut m = Control {
        dim: 2,
        ..Control::default()
    };
    m.u[..2].copy_from_slice(&[1.0, 1.0]);
    m.header.t_pub_ns = now_ns();
    ctl.publish(&m).unwrap();
    std::thread::sleep(Duration::from_millis(30));
    for _ in 0..5 {
        let mut r = m;
        r.u[..2].copy_from_slice(&[-2.9, 2.9]);
        r.waypoints_reached = 4242;
        r.header.t_pub_ns = now_ns();
        rogue.publish(&r).unwrap();
        std::thread::sleep(Duration::from_millis(30));
    }
    let s = stats_until(&stats, StageKind::Plant, &mut last, |s| s.rejected >= 5);
    stop.store(true, Ordering::Relaxed);
    plant.join().unwrap().unwrap();
    while let Some(t) = truth.receive().unwrap() {
        assert!(
            t.u[..2] == [0.0, 0.0] || t.u[..2] == [1.0, 1.0],
            "{:?}",
            &t.u[..2]
        );
    }
    drop((ctl, rogue, truth, stats, bus, rogue_bus));
    assert_eq!(s.rejected_by_reason[Reason::Foreign as usize], 5, "{s:?}");
    assert_eq!(s.waypoints_reached, 0);
    let _ = cleanup::remove_prefix(&prefix);
    assert!(cleanup::resources(&prefix).is_empty());
}
