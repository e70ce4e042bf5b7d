//! The filter stage: observation books, one belief per observation.

use super::*;

/// Simulated ship observations on a real-time schedule: (obs, true state).
fn ship_observations(cfg: &PipelineConfig, n: usize, t0: u64) -> Vec<(Observation, [f64; 4])> {
    let model = cfg.model().unwrap();
    let mut sim = plant::Simulator::new(model, &cfg.plant.initial_state, 42, 1e-3);
    let dt_ns = (1e9 / cfg.plant.sensor_rate_hz) as u64;
    let mut out = Vec::new();
    for k in 0..n {
        sim.advance(dt_ns as f64 * 1e-9);
        let mut y = [0.0; 2];
        sim.measure(&mut y);
        let mut o = Observation {
            channel: 0,
            mask: 0b11,
            dim: 2,
            ..Observation::default()
        };
        o.y[..2].copy_from_slice(&y);
        o.header.seq = k as u64;
        o.header.t_valid_ns = t0 + (k as u64 + 1) * dt_ns;
        o.trace.t_meas_ns = o.header.t_valid_ns;
        o.trace.sensor_seq = k as u64;
        let x = sim.state();
        out.push((o, [x[0], x[1], x[2], x[3]]));
    }
    out
}

#[test]
fn seq_tracker_from_zero_counts_what_came_before_the_first_message() {
    let mut t = SeqTracker::from_zero();
    assert_eq!(t.observe(3), 3);
    assert_eq!(t.observe(4), 0);
    assert_eq!(t.observe(7), 2);
    // A restarted publisher (numbering again from 0): no gap.
    assert_eq!(t.observe(0), 0);
    let mut r = SeqTracker::default();
    assert_eq!(r.observe(3), 0);
    assert_eq!(r.observe(5), 1);
    let mut m = Metrics::new(0, &[], 0);
    m.count_drop(DropReason::Lost, 3);
    m.count_drop(DropReason::Shutdown, 1);
    let s = m.to_stats(&StageIdentity::plain(StageKind::Filter));
    assert_eq!(s.dropped, 4);
    assert_eq!(s.dropped_by_reason, [3, 0, 0, 1]);
}

#[test]
fn the_filter_accounts_for_every_observation_published() {
    // A 1 ns budget: every filtered observation is a deadline miss, and
    // its log has to reach the launcher in the stats message.
    let cfg = test_config(&[
        "filter.backend=ekf",
        "ingest.max_age_s=10",
        "stages.filter.budget_us=0.001",
    ]);
    let _c = Cleanup(cfg.run.prefix.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let bus = Bus::open(&cfg.bus(), "test").unwrap();
    let stats = bus.subscriber::<StageStats>().unwrap();
    let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
    let mut obs = bus.publisher::<Observation>().unwrap();
    let h = spawn(StageKind::Filter, &cfg, &stop);
    wait_ready(&stats, 1);
    let clock = MonotonicClock;
    let n = 80u64;
    let t_begin = clock.now_ns();
    for (o, _) in ship_observations(&cfg, n as usize, clock.now_ns()) {
        let k = o.header.seq;
        // Never delivered: 0..3 (as if published before the filter
        // connected) and 10, 11 (as if overwritten in its queue).
        if k < 3 || k == 10 || k == 11 {
            continue;
        }
        let mut o = o;
        o.header.t_pub_ns = clock.now_ns();
        obs.publish(&o).unwrap();
        // One at a time up to 20, then a burst the filter cannot keep up
        // with (its queue overflows), and the stop right after it.
        if k < 20 {
            poll_until(Duration::from_secs(10), || beliefs.receive().unwrap());
        }
    }
    stop.store(true, Ordering::SeqCst);
    let fin = h.join().unwrap().unwrap();
    let t_end = clock.now_ns();
    let by = |r: DropReason| fin.dropped_by_reason[r as usize];
    assert_eq!(fin.processed + fin.dropped + fin.rejected, n, "{fin:?}");
    assert_eq!(fin.rejected, 0);
    assert!(fin.processed >= 15, "{fin:?}");
    assert!(by(DropReason::Lost) >= 5, "{fin:?}");
    assert!(by(DropReason::Shutdown) <= Observation::QOS.default_buffer as u64 + 1);
    assert_eq!(by(DropReason::Stale) + by(DropReason::Superseded), 0);
    assert_eq!(fin.dropped_by_reason.iter().sum::<u64>(), fin.dropped);
    // Every filtered observation missed; the log lists the latest 32 of
    // them, in order, inside the test's time, and counts the rest.
    let cap = crate::ipc::STATS_MISSES as u64;
    assert_eq!(fin.deadline_misses, fin.processed);
    let listed: Vec<_> = fin.misses().collect();
    assert_eq!(listed.len() as u64, fin.processed.min(cap));
    assert_eq!(
        fin.miss_log_overwritten,
        fin.processed - listed.len() as u64
    );
    for w in listed.windows(2) {
        assert!(w[0].start_ns + w[0].wall_ns <= w[1].start_ns, "{w:?}");
    }
    for m in &listed {
        assert!(
            m.start_ns >= t_begin && m.start_ns + m.wall_ns <= t_end,
            "{m:?}"
        );
        // The filter marks each message's start: CPU time and switches
        // are measured.
        assert!(
            m.wall_ns > 1 && m.cpu_ns.is_some() && m.switches.is_some(),
            "{m:?}"
        );
    }
    // The final report that went over the stats channel carries the same log.
    let mut last = None;
    while let Some(s) = stats.receive().unwrap() {
        last = Some(s);
    }
    let last = last.expect("no stats report after the first");
    assert_ne!(last.flags & crate::ipc::stats_flags::FINAL, 0);
    assert_eq!(last.miss_log, fin.miss_log);
    assert_eq!(last.miss_log_overwritten, fin.miss_log_overwritten);
}

#[test]
fn filter_loop_publishes_one_belief_per_observation_and_tracks_the_ship() {
    for backend in ["pf", "ekf", "ukf"] {
        let cfg = test_config(&[
            &format!("filter.backend={backend}"),
            "filter.pf.particles=500",
            // The observations below are stamped up to 2 s ahead of the
            // clock (published faster than their sensor rate).
            "ingest.max_age_s=10",
        ]);
        let _c = Cleanup(cfg.run.prefix.clone());
        let stop = Arc::new(AtomicBool::new(false));
        let bus = Bus::open(&cfg.bus(), "test").unwrap();
        let stats = bus.subscriber::<StageStats>().unwrap();
        let beliefs = bus.subscriber_with::<Belief>(256, false).unwrap();
        let mut obs = bus.publisher::<Observation>().unwrap();
        let h = spawn(StageKind::Filter, &cfg, &stop);
        wait_ready(&stats, 1);

        let clock = MonotonicClock;
        let n = 200;
        let data = ship_observations(&cfg, n, clock.now_ns());
        let (mut se_filter, mut se_raw, mut count) = (0.0, 0.0, 0);
        for (o, x) in &data {
            let mut o = *o;
            let now = clock.now_ns();
            o.trace.t_sensor_pub_ns = now;
            o.trace.t_ingest_in_ns = now;
            o.trace.t_ingest_out_ns = now;
            o.header.t_pub_ns = now;
            obs.publish(&o).unwrap();
            let b = poll_until(Duration::from_secs(10), || beliefs.receive().unwrap());
            assert_eq!(b.trace.sensor_seq, o.trace.sensor_seq);
            assert_eq!(b.header.t_valid_ns, o.header.t_valid_ns);
            assert!(
                b.trace.t_filter_in_ns >= now && b.trace.t_filter_out_ns >= b.trace.t_filter_in_ns
            );
            assert_eq!(b.status & crate::ipc::belief_status::UPDATE_REFUSED, 0);
            if o.header.seq >= 50 {
                let mut raw = [0.0; 2];
                assert!(cfg.system().raw_position(&o.y, &mut raw));
                se_filter += (b.mean[0] - x[0]).powi(2) + (b.mean[1] - x[1]).powi(2);
                se_raw += (raw[0] - x[0]).powi(2) + (raw[1] - x[1]).powi(2);
                count += 1;
            }
        }
        stop.store(true, Ordering::SeqCst);
        let fin = h.join().unwrap().unwrap();
        let (rmse, rmse_raw) = (
            (se_filter / count as f64).sqrt(),
            (se_raw / count as f64).sqrt(),
        );
        assert!(
            rmse < 0.7 * rmse_raw,
            "{backend}: rmse {rmse} vs raw {rmse_raw}"
        );
        assert_eq!(fin.processed, n as u64);
        assert_eq!(fin.rejected, 0);
        assert_eq!(fin.dropped, 0);
        assert_eq!(fin.compute.count, n as u64);
        // The PF counts collapsed updates (none on its own model's data);
        // the Gaussian filters have none to count.
        let counted = fin.flags & crate::ipc::stats_flags::COLLAPSES_COUNTED != 0;
        assert_eq!(counted, backend == "pf", "{backend}");
        assert_eq!(fin.ess_collapses, 0, "{backend}");
        let hop = fin.hop(Hop::SensorToBelief).unwrap();
        assert!(
            hop.count > 0 && hop.count < n as u64,
            "warm-up excluded: {}",
            hop.count
        );
    }
}

/// The stats message carries the backend's collapse count: a PF whose
/// update meets an observation far in its tail counts it, with the flag
/// set; an EKF reports none and no flag.
#[test]
fn collapsed_updates_reach_the_stats_message() {
    for (backend, want) in [("pf", Some(1)), ("ekf", None)] {
        let cfg = test_config(&[
            &format!("filter.backend={backend}"),
            "filter.pf.particles=500",
        ]);
        let mut f = crate::stage::filter::make_filter(&cfg, 0.0).unwrap();
        f.predict(0.01, &[0.0; 2][..f.dims().control]).unwrap();
        let b = f.belief();
        // Range and bearing far outside the prior's spread.
        let mut y = [0.0; crate::MAX_OBS];
        let m = f.dims().obs;
        crate::model::SdeModel::obs_mean(&cfg.model().unwrap(), &b.mean[..4], &mut y[..m]);
        y[0] += 50.0;
        let _ = f.update(&crate::model::Measurement::full(&y[..m]));
        assert_eq!(f.ess_collapses(), want, "{backend}");
        let mut metrics = Metrics::new(0, &[], 0);
        metrics.ess_collapses = f.ess_collapses();
        let s = metrics.to_stats(&StageIdentity::plain(StageKind::Filter));
        let counted = s.flags & crate::ipc::stats_flags::COLLAPSES_COUNTED != 0;
        assert_eq!(counted, want.is_some());
        assert_eq!(s.ess_collapses, want.unwrap_or(0));
    }
}
