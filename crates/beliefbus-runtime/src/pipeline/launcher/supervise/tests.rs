//! The supervision decisions fed synthetic exit statuses and clock values.

use super::*;
use crate::pipeline::supervisor::RestartOn;

/// A wait status: exit code `c`.
fn exited(c: i32) -> ExitStatus {
    ExitStatus::from_raw(c << 8)
}

/// A wait status: killed by `sig`.
fn killed(sig: i32) -> ExitStatus {
    ExitStatus::from_raw(sig)
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn policy() -> RestartPolicy {
    RestartPolicy {
        backoff_ms: 100.0,
        max_backoff_ms: 800.0,
        reset_after_s: 10.0,
        ..RestartPolicy::default()
    }
}

/// Let incarnation of `s` die with `status` after living `lived`, at
/// `t0 + offset`; returns the verdict and the death's clock.
fn die(s: &mut Stage, status: ExitStatus, lived: Duration) -> (DeathVerdict, Instant) {
    let now = s.started + lived;
    s.exit = Some(status);
    let v = s.decide_death(&policy(), now, 1_000);
    (v, now)
}

#[test]
fn crash_loop_backs_off_exponentially_up_to_the_cap_and_a_long_life_resets_it() {
    let t0 = Instant::now();
    let mut s = Stage::without_process(StageKind::Filter, 10, t0);
    // A crash loop: each incarnation dies 50 ms after it started.
    let mut waits = Vec::new();
    for n in 0..6u32 {
        let (v, now) = die(&mut s, killed(libc::SIGSEGV), ms(50));
        let Decision::Restart { after, consecutive } = v.decision else {
            panic!("gave up: {v:?}");
        };
        assert_eq!(consecutive, n + 1);
        assert_eq!(s.restart_at, Some(now + after));
        // Not due one ms before, due at the time.
        assert!(!s.restart_due(now + after - ms(1)));
        assert!(s.restart_due(now + after));
        waits.push(after.as_millis());
        s.reincarnated(11 + n, now + after);
        assert_eq!(s.restart_at, None);
    }
    assert_eq!(waits, [100, 200, 400, 800, 800, 800]);
    assert_eq!(s.restart.restarts, 6);
    // An incarnation that lived reset_after_s: back to the first delay.
    let (v, _) = die(&mut s, exited(1), Duration::from_secs(10));
    assert_eq!(
        v.decision,
        Decision::Restart {
            after: ms(100),
            consecutive: 1
        }
    );
    assert_eq!(s.deaths.len(), 7);
    assert_eq!(s.deaths[0], "signal 11");
    assert_eq!(s.deaths[6], "exit 1");
}

#[test]
fn clean_exit_under_on_failure_and_any_exit_under_never_end_the_run() {
    let mut s = Stage::without_process(StageKind::Ingest, 1, Instant::now());
    let (v, _) = die(&mut s, exited(0), ms(5));
    assert_eq!(v.decision, Decision::GiveUp(GiveUpReason::CleanExit));
    assert_eq!(v.cause, "exit 0");
    assert_eq!(s.restart_at, None);

    let never = RestartPolicy {
        on: RestartOn::Never,
        ..policy()
    };
    let mut s = Stage::without_process(StageKind::Ingest, 1, Instant::now());
    s.exit = Some(killed(libc::SIGKILL));
    let v = s.decide_death(&never, Instant::now(), 0);
    assert_eq!(v.decision, Decision::GiveUp(GiveUpReason::PolicyNever));
    assert_eq!(s.restart_at, None);
}

#[test]
fn max_restarts_and_the_fatal_exit_end_the_run() {
    let p = RestartPolicy {
        max_restarts: Some(2),
        ..policy()
    };
    let mut s = Stage::without_process(StageKind::Refine, 1, Instant::now());
    let mut decisions = Vec::new();
    for _ in 0..3 {
        s.exit = Some(exited(3));
        let now = s.started + ms(1);
        decisions.push(s.decide_death(&p, now, 0).decision);
        s.reincarnated(2, now);
    }
    assert!(matches!(decisions[0], Decision::Restart { .. }));
    assert!(matches!(decisions[1], Decision::Restart { .. }));
    assert_eq!(
        decisions[2],
        Decision::GiveUp(GiveUpReason::TooManyRestarts)
    );

    let mut s = Stage::without_process(StageKind::Filter, 1, Instant::now());
    let (v, _) = die(&mut s, exited(crate::stage::FATAL_EXIT), ms(1));
    assert_eq!(v.decision, Decision::GiveUp(GiveUpReason::Fatal));
}

#[test]
fn a_hang_is_named_hang_whatever_signal_ended_it_and_clears() {
    let mut s = Stage::without_process(StageKind::Control, 1, Instant::now());
    s.hung = true;
    let (v, _) = die(&mut s, killed(libc::SIGKILL), ms(3000));
    assert_eq!(v.cause, "hang");
    assert!(matches!(v.decision, Decision::Restart { .. }));
    assert!(!s.hung);
    // The next death is named by its status again.
    let (v, _) = die(&mut s, killed(libc::SIGKILL), ms(1));
    assert_eq!(v.cause, "signal 9");
}

#[test]
fn a_chaos_kill_is_dated_at_the_kill_and_named_chaos_if_the_sigkill_did_it() {
    let mut s = Stage::without_process(StageKind::Filter, 1, Instant::now());
    s.chaos_kill_ns = Some(777);
    let (v, _) = die(&mut s, killed(libc::SIGKILL), ms(10));
    assert_eq!((v.cause.as_str(), v.t_death_ns), ("chaos", 777));
    assert_eq!(s.chaos_kill_ns, None);
    // Chaos aimed at it but it died of something else first: named by its
    // status, still dated at the kill.
    s.chaos_kill_ns = Some(888);
    let (v, _) = die(&mut s, exited(2), ms(10));
    assert_eq!((v.cause.as_str(), v.t_death_ns), ("exit 2", 888));
    // No chaos: dated now.
    let (v, _) = die(&mut s, exited(2), ms(10));
    assert_eq!(v.t_death_ns, 1_000);
}

#[test]
fn death_and_status_names() {
    assert_eq!(death_of(Some(&exited(4)), false), Death::Exit(4));
    assert_eq!(death_of(Some(&killed(15)), false), Death::Signal(15));
    assert_eq!(death_of(Some(&exited(0)), true), Death::Hang);
    assert_eq!(death_of(None, false), Death::Exit(-1));
    assert_eq!(describe(&exited(0)), "exit 0");
    assert_eq!(describe(&killed(9)), "signal 9");
    assert_eq!(cause_of(Death::Signal(15), true), "signal 15");
    assert_eq!(
        give_up_text(GiveUpReason::TooManyRestarts),
        "restart.max_restarts is used up"
    );
}

#[test]
fn heartbeat_deadline_runs_from_the_last_report_or_from_the_start() {
    let t0 = Instant::now();
    let (limit, start) = (ms(2000), ms(20_000));
    // Not reported yet: the start-up deadline, from the spawn.
    assert_eq!(
        heartbeat_overdue(t0 + ms(19_000), None, t0, limit, start),
        None
    );
    assert_eq!(
        heartbeat_overdue(t0 + ms(20_001), None, t0, limit, start),
        Some(start)
    );
    // Reported at 5 s: overdue strictly after 7 s.
    let seen = Some(t0 + ms(5000));
    assert_eq!(
        heartbeat_overdue(t0 + ms(7000), seen, t0, limit, start),
        None
    );
    assert_eq!(
        heartbeat_overdue(t0 + ms(7001), seen, t0, limit, start),
        Some(limit)
    );
    // A report in the future of `now` (clock read earlier) is not overdue.
    assert_eq!(heartbeat_overdue(t0, seen, t0, limit, start), None);
}

fn rt(core: Option<usize>, prio: Option<u8>) -> RtSettings {
    RtSettings {
        core,
        fifo_priority: prio,
        ..RtSettings::default()
    }
}

#[test]
fn escalation_kills_higher_priority_stages_on_the_same_core_highest_first() {
    use StageKind::*;
    let settings = |k: StageKind| match k {
        Filter => rt(Some(1), Some(10)), // the hung one
        Control => rt(Some(1), Some(50)),
        Ingest => rt(Some(1), Some(80)),
        Refine => rt(Some(0), Some(90)), // another core
        Plant => rt(Some(1), Some(10)),  // same priority: cannot starve it
    };
    let stages = [
        (Control, true),
        (Refine, true),
        (Filter, true),
        (Ingest, true),
        (Plant, true),
    ];
    assert_eq!(starvers(2, &stages, settings), [3, 0]);
    // Not running: nobody to kill.
    let mut gone = stages;
    gone[3].1 = false;
    assert_eq!(starvers(2, &gone, settings), [0]);
    // Unpinned stages share "no core": the same rule applies.
    let unpinned = |k: StageKind| rt(None, (k == Ingest).then_some(5));
    assert_eq!(starvers(2, &stages, unpinned), [3]);
    // Nothing outranks the top priority.
    assert!(starvers(3, &stages, settings).is_empty());
}

#[test]
fn chaos_picks_among_running_allowed_stages() {
    use StageKind::*;
    let stages = [
        (Control, true),
        (Filter, false),
        (Ingest, true),
        (Plant, true),
    ];
    assert_eq!(chaos_candidates(&stages, &[]), [0, 2, 3]);
    assert_eq!(chaos_candidates(&stages, &[Filter, Ingest]), [2]);
    assert!(chaos_candidates(&stages, &[Refine]).is_empty());
}

#[test]
fn recovery_completes_when_the_new_process_reported_and_a_post_death_output_went_out() {
    let mut r = Recovery {
        kind: StageKind::Filter,
        cause: "chaos".into(),
        t_death_ns: 1_000_000,
        pid: None,
        backoff_ms: 20.0,
        reported_ns: None,
        output_ns: None,
    };
    let out = |sensor, publ| Output {
        t_sensor_pub_ns: sensor,
        t_pub_ns: publ,
    };
    // Before the restart nothing counts.
    assert_eq!(
        r.observe(true, &[out(2_000_000, 2_500_000)], 3_000_000),
        None
    );
    assert_eq!(r.reported_ns, None);
    r.pid = Some(42);
    // Outputs of pre-death samples do not count; the new process has not
    // reported yet.
    assert_eq!(
        r.observe(false, &[out(900_000, 5_000_000)], 4_000_000),
        None
    );
    assert_eq!(r.output_ns, None);
    // A post-death output (the earliest one) and later the report.
    let outs = [
        out(900_000, 1_200_000),
        out(1_500_000, 6_000_000),
        out(1_600_000, 5_500_000),
    ];
    assert_eq!(r.observe(false, &outs, 5_000_000), None);
    assert_eq!(r.output_ns, Some(5_500_000));
    // Recovered at max(report 7 ms, output 5.5 ms) − death 1 ms = 6 ms.
    assert_eq!(r.observe(true, &outs, 7_000_000), Some(6.0));
}

#[test]
fn counters_span_every_incarnation() {
    let mut s = Stage::without_process(StageKind::Filter, 1, Instant::now());
    let mut a = StageStats {
        processed: 10,
        dropped: 2,
        rejected: 1,
        deadline_misses: 3,
        deadline_misses_warmup: 2,
        late: 4,
        controls_received: 5,
        processed_after_warmup: 6,
        ess_collapses: 9,
        ..StageStats::default()
    };
    a.dropped_by_reason[0] = 2;
    s.carry(&a);
    s.carry(&a);
    let last = StageStats {
        processed: 7,
        ess_collapses: 1,
        deadline_misses_warmup: 1,
        compute: crate::ipc::Percentiles {
            count: 3,
            ..Default::default()
        },
        ..StageStats::default()
    };
    let t = s.with_earlier(last);
    assert_eq!(
        (t.processed, t.dropped, t.rejected, t.deadline_misses),
        (27, 4, 2, 6)
    );
    assert_eq!(
        (t.late, t.controls_received, t.processed_after_warmup),
        (8, 10, 12)
    );
    assert_eq!(t.dropped_by_reason[0], 4);
    assert_eq!(t.ess_collapses, 19);
    // Each incarnation warms up again: 2 + 2 + 1 warm-up misses.
    assert_eq!(t.deadline_misses_warmup, 5);
    // Histograms are the last incarnation's.
    assert_eq!(t.compute.count, 3);
}

/// A report whose miss log lists misses starting at `starts` (ns), with
/// `overwritten` more pushed out before them.
fn with_misses(starts: std::ops::Range<u64>, overwritten: u64) -> StageStats {
    let mut st = StageStats {
        deadline_misses: starts.end - starts.start + overwritten,
        miss_log_overwritten: overwritten,
        ..StageStats::default()
    };
    for (slot, t) in st.miss_log.iter_mut().zip(starts) {
        *slot = crate::ipc::MissStats {
            start_ns: t,
            wall_ns: 500 + t,
            cpu_ns: t,
            switches: 1,
            kind: 2,
            reserved: 0,
            minor_faults: 2 * t,
            major_faults: 0,
        };
    }
    st
}

fn listed_starts(st: &StageStats) -> Vec<u64> {
    st.misses().map(|m| m.start_ns).collect()
}

#[test]
fn the_miss_log_keeps_the_latest_misses_of_every_incarnation() {
    use crate::ipc::STATS_MISSES;
    let cap = STATS_MISSES as u64;
    // First incarnation: 5 misses, all listed. Second: 40, the last 32
    // listed. Last: 3.
    let mut s = Stage::without_process(StageKind::Control, 1, Instant::now());
    s.carry(&with_misses(100..105, 0));
    let t = s.with_earlier(with_misses(200..203, 0));
    assert_eq!(listed_starts(&t), [100, 101, 102, 103, 104, 200, 201, 202]);
    assert_eq!((t.deadline_misses, t.miss_log_overwritten), (8, 0));
    s.carry(&with_misses(1_000..1_000 + cap, 8));
    let t = s.with_earlier(with_misses(2_000..2_003, 0));
    // 48 misses: the latest 32 are the second incarnation's last 29 and
    // the last one's 3; the other 16 are counted.
    let want: Vec<u64> = (1_003..1_000 + cap).chain(2_000..2_003).collect();
    assert_eq!(listed_starts(&t), want);
    assert_eq!(t.deadline_misses, 5 + 40 + 3);
    assert_eq!(t.miss_log_overwritten, 16);
    assert_eq!(t.deadline_misses, cap + t.miss_log_overwritten);
    // Every field travels with its entry.
    let m = t.misses().next().unwrap();
    assert_eq!(
        (m.wall_ns, m.cpu_ns, m.switches, m.faults.map(|f| f.minor)),
        (1_503, Some(1_003), Some(1), Some(2_006))
    );
    // A last incarnation with a full log of its own lists only its own.
    let t = s.with_earlier(with_misses(3_000..3_000 + cap, 2));
    assert_eq!(listed_starts(&t), (3_000..3_000 + cap).collect::<Vec<_>>());
    assert_eq!(t.miss_log_overwritten, 13 + 32 + 2);
    assert_eq!(t.deadline_misses, cap + t.miss_log_overwritten);
}
