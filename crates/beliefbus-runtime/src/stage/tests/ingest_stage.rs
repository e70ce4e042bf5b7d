//! The ingest stage: validation, channel binding, merging, its loop.

use super::*;

#[test]
fn validator_rejects_each_reason_and_accepts_good_samples() {
    use ingest::{Reason, Validator};
    let cfg = test_config(&[]);
    let mut v = Validator::new(&cfg).unwrap();
    let mut o = Observation::default();
    let now = 10_000_000_000u64;
    let ms = 1_000_000u64;
    let ok = |v: &mut Validator, s: &SensorSample, o: &mut Observation| v.check(s, now, o);
    assert_eq!(
        ok(&mut v, &sample(0, 0, now - 100 * ms, &[5.0, 0.1]), &mut o),
        Ok(0)
    );
    assert_eq!(o.mask, 0b11);
    assert_eq!(o.y[..2], [5.0, 0.1]);
    assert_eq!(o.trace.t_meas_ns, now - 100 * ms);
    let cases = [
        (
            sample(7, 1, now - 90 * ms, &[5.0, 0.1]),
            Reason::UnknownChannel,
        ),
        (sample(0, 1, now - 90 * ms, &[5.0]), Reason::Dimension),
        (
            sample(0, 1, now - 90 * ms, &[f64::NAN, 0.1]),
            Reason::NonFinite,
        ),
        (
            sample(0, 1, now - 90 * ms, &[f64::INFINITY, 0.1]),
            Reason::NonFinite,
        ),
        (
            sample(0, 1, now - 90 * ms, &[5.0, 0.1]).with_noise_std(&[0.0, 1.0]),
            Reason::Invalid,
        ),
        (
            sample(0, 1, now + 10_000 * ms, &[5.0, 0.1]),
            Reason::Invalid,
        ),
        (sample(0, 0, now - 90 * ms, &[5.0, 0.1]), Reason::Duplicate),
        (
            sample(0, 1, now - 110 * ms, &[5.0, 0.1]),
            Reason::TimeBackwards,
        ),
        // Both older than the last accepted and older than max_age: age is
        // checked first.
        (sample(0, 1, now - 900 * ms, &[5.0, 0.1]), Reason::TooOld),
    ];
    for (s, want) in cases {
        assert_eq!(ok(&mut v, &s, &mut o), Err(want), "{s:?}");
    }
    // Too old: the newest accepted was at now − 100 ms, so this one is in
    // order but older than max_age (0.5 s) — use a fresh validator.
    let mut v2 = Validator::new(&cfg).unwrap();
    assert_eq!(
        ok(&mut v2, &sample(0, 0, now - 600 * ms, &[5.0, 0.1]), &mut o),
        Err(Reason::TooOld)
    );
    // A gap in sequence numbers is reported as lost samples: seq 1 was seen
    // (the too-old one passed the duplicate check), 2 and 3 were lost.
    assert_eq!(
        ok(&mut v, &sample(0, 4, now - 80 * ms, &[5.0, 0.1]), &mut o),
        Ok(2)
    );
    assert_eq!(v.lost(), 2);
    // Rate: max 200 Hz with a burst of 3 — samples 0.1 ms apart exhaust it.
    let mut rejected = 0;
    for i in 0..10u64 {
        let s = sample(0, 5 + i, now - 70 * ms + i * 100_000, &[5.0, 0.1]);
        if ok(&mut v, &s, &mut o) == Err(Reason::Rate) {
            rejected += 1;
        }
    }
    assert!(
        rejected >= 6,
        "rate limiter let too many through: {rejected} rejected"
    );
}

/// The finding: one sample with sequence number 2⁶² made ingest reject
/// every later genuine sample as `duplicate`. Now it is rejected on its own
/// (`seq_jump`) and the genuine ones after it are all accepted; a genuine
/// gap within what the rate allows is still accepted (and counted lost).
#[test]
fn a_huge_sequence_jump_is_rejected_and_does_not_poison_later_samples() {
    use ingest::{Reason, Validator};
    let cfg = test_config(&[]);
    let mut v = Validator::new(&cfg).unwrap();
    let mut o = Observation::default();
    let ms = 1_000_000u64;
    let now = 10_000_000_000u64;
    let t = |k: u64| now - 500 * ms + 10 * ms * k;
    assert!(v
        .check(&sample(0, 0, t(0), &[5.0, 0.1]), t(0), &mut o)
        .is_ok());
    assert_eq!(
        v.check(&sample(0, 1 << 62, t(1), &[5.0, 0.1]), t(1), &mut o),
        Err(Reason::SeqJump)
    );
    for k in 1..40 {
        assert_eq!(
            v.check(&sample(0, k, t(k), &[5.0, 0.1]), t(k), &mut o),
            Ok(0),
            "genuine sample {k}"
        );
    }
    // 30 samples lost over 0.3 s: inside the rate's allowance.
    assert_eq!(
        v.check(&sample(0, 70, t(70), &[5.0, 0.1]), t(70), &mut o),
        Ok(30)
    );
}

/// A channel belongs to the first publisher whose sample it accepted:
/// another publisher's samples (the finding: a rogue's σ = 1e-3 samples,
/// weighted heavily) are rejected while the owner stays connected; once it
/// is gone the next one is bound with fresh numbering (a restarted sensor).
#[test]
fn a_channel_is_bound_to_its_first_publisher_until_it_is_gone() {
    use ingest::{Reason, Validator};
    let cfg = test_config(&[]);
    let mut v = Validator::new(&cfg).unwrap();
    let mut o = Observation::default();
    let ms = 1_000_000u64;
    let now = 10_000_000_000u64;
    let t = |k: u64| now - 500 * ms + 10 * ms * k;
    let (genuine, rogue) = (11u128, 22u128);
    let alive = |p: u128| p == genuine;
    let s = |k: u64| sample(0, k, t(k), &[5.0, 0.1]);
    assert!(v.check_from(&s(0), genuine, &alive, t(0), &mut o).is_ok());
    let r = sample(0, 1, t(1), &[50.0, 0.1]).with_noise_std(&[1e-3, 1e-3]);
    assert_eq!(
        v.check_from(&r, rogue, &alive, t(1), &mut o),
        Err(Reason::ForeignPublisher)
    );
    for k in 1..10 {
        assert!(v.check_from(&s(k), genuine, &alive, t(k), &mut o).is_ok());
    }
    // The genuine publisher is gone: a restarted one (new port) numbering
    // from 0 is bound.
    let restarted = 33u128;
    let alive = |p: u128| p == restarted;
    let mut first = s(10);
    first.seq = 0;
    assert!(v
        .check_from(&first, restarted, &alive, t(10), &mut o)
        .is_ok());
    assert_eq!(
        v.check_from(&r, rogue, &alive, t(11), &mut o),
        Err(Reason::ForeignPublisher)
    );
    let mut next = s(12);
    next.seq = 1;
    assert!(v
        .check_from(&next, restarted, &alive, t(12), &mut o)
        .is_ok());
}

#[test]
fn a_rate_rejected_sample_never_breaks_the_time_checks() {
    use ingest::{Reason, Validator};
    // One channel limited to 100 Hz: after the burst of 3, a sample 1 ms
    // later is rejected for rate (its time is remembered by the limiter);
    // a sample measured between the last accepted one and that rejected one
    // is then in order for the channel and must be judged, not underflow.
    let cfg =
        test_config(&["ingest.channels=[{id = 0, components = [0, 1], max_rate_hz = 100.0}]"]);
    let mut v = Validator::new(&cfg).unwrap();
    let mut o = Observation::default();
    let now = 10_000_000_000u64;
    let ms = 1_000_000u64;
    let t0 = now - 100 * ms;
    for k in 0..3u64 {
        assert_eq!(
            v.check(&sample(0, k, t0 + k * ms, &[5.0, 0.1]), now, &mut o),
            Ok(0)
        );
    }
    // Tokens: 3 → 2 → 1.1 → 0.2; 3 ms later 0.5 < 1.
    assert_eq!(
        v.check(&sample(0, 3, t0 + 5 * ms, &[5.0, 0.1]), now, &mut o),
        Err(Reason::Rate)
    );
    // In order for the channel (after t0 + 2 ms), before the limiter's
    // last time: no refill, still limited.
    assert_eq!(
        v.check(&sample(0, 4, t0 + 3 * ms, &[5.0, 0.1]), now, &mut o),
        Err(Reason::Rate)
    );
    // 35 ms later the bucket has refilled; the rate-rejected samples were
    // seen, not lost.
    assert_eq!(
        v.check(&sample(0, 5, t0 + 40 * ms, &[5.0, 0.1]), now, &mut o),
        Ok(0)
    );
    assert_eq!(v.lost(), 0);
}

#[test]
fn ingest_merges_two_channels_in_measurement_order() {
    // Range on channel 1, bearing on channel 2, arriving out of order.
    let cfg = test_config(&[
        "ingest.channels=[{id = 1, components = [0]}, {id = 2, components = [1]}]",
        "ingest.reorder_window_ms=200.0",
    ]);
    let _c = Cleanup(cfg.run.prefix.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let bus = Bus::open(&cfg.bus(), "test").unwrap();
    let stats = bus.subscriber::<StageStats>().unwrap();
    let obs = bus.subscriber_with::<Observation>(32, false).unwrap();
    let mut sensor = bus.publisher::<SensorSample>().unwrap();
    let h = spawn(StageKind::Ingest, &cfg, &stop);
    wait_ready(&stats, 1);
    let ms = 1_000_000u64;
    let t0 = MonotonicClock.now_ns();
    let mut recv = Vec::new();
    let take = |recv: &mut Vec<Observation>| {
        while let Some(o) = obs.receive().unwrap() {
            recv.push(o);
        }
    };
    // (channel, seq, t): channel 2's sample at t0+5 arrives after channel
    // 1's at t0+10; channel 1's at t0+12 is held until channel 2 passes it.
    let sends = [
        (1, 0, 0),
        (2, 0, 1),
        (1, 1, 10),
        (2, 1, 5),
        (1, 2, 12),
        (2, 2, 20),
    ];
    for (c, seq, dt) in sends {
        sensor
            .publish(&sample(
                c,
                seq,
                t0 + dt * ms,
                &[if c == 1 { 5.0 } else { 0.3 }],
            ))
            .unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    // The last one leaves when its window expires.
    poll_until(Duration::from_secs(10), || {
        take(&mut recv);
        (recv.len() >= 6).then_some(())
    });
    // In order for channel 1 (its last was t0+12) but measured before the
    // last forwarded observation (t0+20): too late for the filter.
    sensor.publish(&sample(1, 3, t0 + 15 * ms, &[5.0])).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    take(&mut recv);
    stop.store(true, Ordering::SeqCst);
    let fin = h.join().unwrap().unwrap();
    take(&mut recv);
    let got: Vec<(u32, u64)> = recv
        .iter()
        .map(|o| (o.channel, (o.header.t_valid_ns - t0) / ms))
        .collect();
    assert_eq!(got, vec![(1, 0), (2, 1), (2, 5), (1, 10), (1, 12), (2, 20)]);
    for o in &recv {
        let want = if o.channel == 1 { 0b01 } else { 0b10 };
        assert_eq!(o.mask, want, "each channel fills its own component");
    }
    assert_eq!(fin.processed, 6);
    assert_eq!(fin.rejected_by_reason[ingest::Reason::TooOld as usize], 1);
    assert_eq!(fin.rejected, 1);
}

#[test]
fn ingest_loop_forwards_valid_samples_in_order_and_counts_rejections() {
    let cfg = test_config(&[]);
    let _c = Cleanup(cfg.run.prefix.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let bus = Bus::open(&cfg.bus(), "test").unwrap();
    let stats = bus.subscriber::<StageStats>().unwrap();
    let obs = bus.subscriber_with::<Observation>(32, false).unwrap();
    let mut sensor = bus.publisher::<SensorSample>().unwrap();
    let h = spawn(StageKind::Ingest, &cfg, &stop);
    wait_ready(&stats, 1);

    let clock = MonotonicClock;
    let t0 = clock.now_ns();
    let mut expected = Vec::new();
    for k in 0..20u64 {
        let t = t0 + k * 10_000_000;
        let mut s = sample(0, k, t, &[4.0 + k as f64 * 0.01, 0.2]);
        s.t_pub_ns = clock.now_ns();
        sensor.publish(&s).unwrap();
        expected.push(k);
        // Interleave bad samples: NaN and a duplicate.
        if k % 5 == 0 {
            sensor
                .publish(&sample(0, k + 1000, t, &[f64::NAN, 0.0]))
                .unwrap();
            sensor.publish(&sample(0, k, t, &[4.0, 0.2])).unwrap();
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let mut got = Vec::new();
    poll_until(Duration::from_secs(10), || {
        while let Some(o) = obs.receive().unwrap() {
            got.push(o);
        }
        (got.len() >= expected.len()).then_some(())
    });
    stop.store(true, Ordering::SeqCst);
    let fin = h.join().unwrap().unwrap();
    assert_eq!(
        got.iter().map(|o| o.trace.sensor_seq).collect::<Vec<_>>(),
        expected
    );
    for (i, o) in got.iter().enumerate() {
        assert_eq!(o.header.seq, i as u64);
        assert!(o.trace.t_ingest_in_ns >= o.trace.t_sensor_pub_ns);
        assert!(o.trace.t_ingest_out_ns >= o.trace.t_ingest_in_ns);
        assert_eq!(o.mask, 0b11);
    }
    assert_eq!(fin.processed, 20);
    let r = &fin.rejected_by_reason;
    assert_eq!(r[ingest::Reason::NonFinite as usize], 4);
    assert_eq!(r[ingest::Reason::Duplicate as usize], 4);
    assert_eq!(fin.rejected, 8);
    assert!(fin.flags & crate::ipc::stats_flags::FINAL != 0);
}
