//! Tests of the budget: the miss split, the miss log, the warm-up count.

use super::*;

#[test]
fn counts_misses_strictly_above_budget() {
    let mut b = Budget::new(100);
    assert!(!b.record(1_000, 1_050));
    assert!(!b.record(1_000, 1_100));
    assert!(b.record(1_000, 1_101));
    assert_eq!(b.misses(), 1);
    assert_eq!(b.compute().count(), 3);
    let mut none = Budget::new(0);
    assert!(!none.record(0, 1_000_000_000));
}

#[test]
fn lateness_counts_queueing_and_compute_against_the_budget() {
    let mut b = Budget::new(100);
    // Released at 1000, waited 30, computed 60: response 90, on time.
    assert!(!b.record_released(1_000, 1_030, 1_090));
    // Waited 50, computed 60: compute within budget, but late by 10.
    assert!(!b.record_released(1_000, 1_050, 1_110));
    // Unknown release: compute only.
    b.record_released(0, 1_000, 1_500);
    assert_eq!(b.misses(), 1);
    assert_eq!(b.late(), 1);
    assert_eq!(b.compute().count(), 3);
    assert_eq!(b.response().count(), 2);
    assert_eq!(b.response().max(), 110);
}

/// Work on the CPU for about `ns` (the thread's own clock).
fn burn(ns: u64) {
    let t0 = thread_cpu_ns();
    let mut x = 1u64;
    while thread_cpu_ns() - t0 < ns {
        x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
    }
}

#[test]
fn a_miss_spent_off_the_cpu_is_preempted_and_one_spent_computing_is_an_overrun() {
    let budget = 2_000_000; // 2 ms
    let mut b = Budget::new(budget);
    // Descheduled for 3× the budget (a sleep is what a preemption looks
    // like to the thread): a miss, but not the stage's own work.
    b.start();
    let t0 = crate::clock::now_ns();
    std::thread::sleep(std::time::Duration::from_nanos(3 * budget));
    let t1 = crate::clock::now_ns();
    assert!(b.record(t0, t1));
    assert_eq!((b.misses(), b.preempted()), (1, 1));
    // The sleep switched the thread out: this machine, not the host.
    assert_eq!(b.host(), 0);
    let m = *b.miss_log().iter().next().unwrap();
    assert_eq!(
        (m.start_ns, m.wall_ns, m.kind),
        (t0, t1 - t0, MissKind::Preempted)
    );
    assert!(
        m.cpu_ns.unwrap() <= budget && m.switches.unwrap() >= 1,
        "{m:?}"
    );
    // Computing for 3× the budget: an own overrun.
    b.start();
    let t0 = crate::clock::now_ns();
    burn(3 * budget);
    assert!(b.record(t0, crate::clock::now_ns()));
    assert_eq!((b.misses(), b.preempted()), (2, 1));
    // Without a start mark the CPU time runs from the last mark, so an
    // unmarked message is never classed as preempted by mistake.
    let t0 = crate::clock::now_ns();
    std::thread::sleep(std::time::Duration::from_nanos(3 * budget));
    assert!(b.record(t0, crate::clock::now_ns()));
    assert_eq!((b.misses(), b.preempted()), (3, 1));
    let kinds: Vec<_> = b.miss_log().iter().map(|m| m.kind).collect();
    assert_eq!(
        kinds,
        [MissKind::Preempted, MissKind::Overrun, MissKind::Overrun]
    );
    assert!(b.miss_log().iter().nth(1).unwrap().cpu_ns.unwrap() > budget);
}

/// Thread usage by hand: switches, minor and major faults.
fn u(switches: u64, minor_faults: u64, major_faults: u64) -> ThreadUsage {
    ThreadUsage {
        switches,
        minor_faults,
        major_faults,
    }
}

/// A miss by hand: thread CPU clock and usage at the start mark and at
/// the end.
fn miss_at(
    b: &mut Budget,
    start_ns: u64,
    end_ns: u64,
    (cpu0, u0): (u64, ThreadUsage),
    (cpu1, u1): (u64, ThreadUsage),
) -> bool {
    b.start_at(cpu0, u0);
    b.record_probed(start_ns, end_ns, || (cpu1, u1))
}

fn faults(minor: u64, major: u64) -> Option<Faults> {
    Some(Faults { minor, major })
}

#[test]
fn the_log_lists_each_miss_with_its_time_cpu_switches_faults_and_kind() {
    let mut b = Budget::new(100);
    // On time: nothing listed, the clocks are not even read.
    b.start_at(1_000, u(5, 100, 0));
    assert!(!b.record_probed(10_000, 10_100, || panic!("read on time")));
    // 150 wall, 40 on the CPU, no switch, no fault: the host's.
    let m = miss_at(
        &mut b,
        20_000,
        20_150,
        (2_000, u(5, 100, 0)),
        (2_040, u(5, 100, 0)),
    );
    assert!(m);
    // 300 wall, 50 on the CPU, 2 switches, 240 minor faults: preempted.
    let m = miss_at(
        &mut b,
        30_000,
        30_300,
        (3_000, u(7, 100, 0)),
        (3_050, u(9, 340, 0)),
    );
    assert!(m);
    // 200 wall, 180 on the CPU, 3 minor and 1 major fault: an overrun.
    let m = miss_at(
        &mut b,
        40_000,
        40_200,
        (4_000, u(9, 340, 2)),
        (4_180, u(9, 343, 3)),
    );
    assert!(m);
    // Usage unreadable: preempted, switches and faults unknown.
    let m = miss_at(
        &mut b,
        50_000,
        50_101,
        (5_000, ThreadUsage::UNKNOWN),
        (5_010, ThreadUsage::UNKNOWN),
    );
    assert!(m);
    // A compute time at the budget is on time.
    let m = miss_at(
        &mut b,
        60_000,
        60_100,
        (6_000, u(9, 343, 3)),
        (6_000, u(9, 343, 3)),
    );
    assert!(!m);
    let want = [
        (20_000, 150, Some(40), Some(0), faults(0, 0), MissKind::Host),
        (
            30_000,
            300,
            Some(50),
            Some(2),
            faults(240, 0),
            MissKind::Preempted,
        ),
        (
            40_000,
            200,
            Some(180),
            Some(0),
            faults(3, 1),
            MissKind::Overrun,
        ),
        (50_000, 101, Some(10), None, None, MissKind::Preempted),
    ];
    let got: Vec<_> = b
        .miss_log()
        .iter()
        .map(|m| {
            (
                m.start_ns, m.wall_ns, m.cpu_ns, m.switches, m.faults, m.kind,
            )
        })
        .collect();
    assert_eq!(got, want);
    assert_eq!((b.misses(), b.preempted(), b.host()), (4, 3, 1));
    assert_eq!(b.miss_log().overwritten(), 0);
    // Without any start mark the CPU time is unknown and the miss stays
    // the stage's own.
    let mut unmarked = Budget::new(100);
    assert!(unmarked.record_probed(7_000, 7_500, || panic!("no mark to read against")));
    let m = unmarked.miss_log().iter().next().copied().unwrap();
    assert_eq!(
        (m.cpu_ns, m.switches, m.faults, m.kind),
        (None, None, None, MissKind::Overrun)
    );
    assert_eq!((unmarked.misses(), unmarked.preempted()), (1, 0));
}

#[test]
fn every_miss_is_listed_or_counted_out_and_the_counts_match_the_kinds() {
    use crate::miss_log::MISS_LOG_CAPACITY;
    let mut b = Budget::new(100);
    let n = MISS_LOG_CAPACITY as u64 + 9;
    // Miss i: host when i % 3 == 0, preempted when 1, overrun when 2;
    // on-time messages in between are never listed. Miss i takes i
    // minor faults.
    for i in 0..n {
        let t = 1_000_000 * i;
        assert!(!miss_at(
            &mut b,
            t,
            t + 50,
            (10, u(1, 0, 0)),
            (20, u(1, 0, 0))
        ));
        let (cpu, sw) = match i % 3 {
            0 => (60, 1),
            1 => (60, 2),
            _ => (160, 1),
        };
        assert!(miss_at(
            &mut b,
            t + 100,
            t + 300 + i,
            (10, u(1, 7, 0)),
            (10 + cpu, u(sw, 7 + i, 0))
        ));
    }
    let log = b.miss_log();
    assert_eq!(log.len(), MISS_LOG_CAPACITY);
    assert_eq!(log.overwritten(), 9);
    assert_eq!(b.misses(), log.len() as u64 + log.overwritten());
    // The 9 oldest are gone; the rest in order, each its own.
    for (m, i) in log.iter().zip(9..n) {
        let kind = [MissKind::Host, MissKind::Preempted, MissKind::Overrun][(i % 3) as usize];
        assert_eq!(
            (m.start_ns, m.wall_ns, m.kind, m.faults),
            (1_000_000 * i + 100, 200 + i, kind, faults(i, 0))
        );
    }
    // The counters span every miss: 14 of 0..41 are ≡ 0 (mod 3), 14 ≡ 1.
    assert_eq!((b.host(), b.preempted()), (14, 28));
}

#[test]
fn misses_in_the_warm_up_are_counted_apart_and_still_in_the_total() {
    // Warm-up of 1000 ns from the first recorded message (at 5_000,
    // on time): misses starting at 5_000..5_999 are the warm-up's.
    let mut b = Budget::with_warmup(100, 1_000);
    let z = (0, u(0, 0, 0));
    assert!(!miss_at(&mut b, 5_000, 5_050, z, z));
    for (start, warm) in [
        (5_200, true),
        (5_999, true),
        (6_000, false),
        (7_500, false),
        (9_000, false),
    ] {
        let before = b.warmup_misses();
        assert!(miss_at(&mut b, start, start + 101, z, (1, u(1, 0, 0))));
        assert_eq!(b.warmup_misses() - before, warm as u64, "start {start}");
    }
    assert_eq!((b.misses(), b.warmup_misses()), (5, 2));
    assert_eq!(b.warmup_ns(), 1_000);
    // The window opens at the first message even when that one missed,
    // and every miss is in the total, listed or not.
    let mut c = Budget::with_warmup(100, 1_000);
    for i in 0..40u64 {
        assert!(miss_at(&mut c, 8_000 + 100 * i, 8_200 + 100 * i, z, z));
    }
    // Starts 8_000, 8_100, ..., 8_900 are in [8_000, 9_000): 10.
    assert_eq!((c.misses(), c.warmup_misses()), (40, 10));
    assert_eq!(
        c.misses(),
        c.miss_log().len() as u64 + c.miss_log().overwritten()
    );
    // No warm-up: nothing is the warm-up's.
    let mut d = Budget::new(100);
    assert!(miss_at(&mut d, 1, 500, z, z));
    assert_eq!((d.misses(), d.warmup_misses()), (1, 0));
}

#[test]
fn a_miss_spent_faulting_pages_in_lists_its_faults() {
    // Touch 256 fresh anonymous pages inside a message that cannot meet
    // a 1 ns budget: its log entry counts at least one fault a page.
    const PAGES: usize = 256;
    let mut b = Budget::new(1);
    b.start();
    let t0 = crate::clock::now_ns();
    crate::clock::touch_fresh_pages(PAGES);
    assert!(b.record(t0, crate::clock::now_ns()));
    let f = b.miss_log().iter().next().unwrap().faults.unwrap();
    assert!(f.minor >= PAGES as u64, "{f:?}");
    assert_eq!(f.major, 0);
}

#[test]
fn kinds_round_trip_their_wire_ids() {
    for k in MissKind::ALL {
        assert_eq!(MissKind::from_id(k as u32), Some(k));
    }
    assert_eq!(MissKind::from_id(0), None);
    assert_eq!(MissKind::Host.name(), "host");
}

#[test]
fn time_lost_without_a_context_switch_is_the_hosts() {
    let b = 1_000;
    assert_eq!(classify(b, 1_001, 5, 5), MissKind::Overrun);
    assert_eq!(classify(b, 1_001, 5, 7), MissKind::Overrun);
    assert_eq!(classify(b, 400, 5, 6), MissKind::Preempted);
    assert_eq!(classify(b, 400, 5, 5), MissKind::Host);
    assert_eq!(classify(b, 1_000, 9, 9), MissKind::Host);
    // An unreadable count is never the host's.
    assert_eq!(classify(b, 400, u64::MAX, u64::MAX), MissKind::Preempted);
}
