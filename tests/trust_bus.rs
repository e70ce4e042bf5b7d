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
