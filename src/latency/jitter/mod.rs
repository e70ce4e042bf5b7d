//! Jitter: the machine's timer floor and the pipeline against it.
//!
//! **Timer baseline** (after cyclictest): one thread per core, pinned, at
//! SCHED_FIFO when permitted, sleeps to absolute deadlines
//! `t_k = t_0 + k·T` with `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`
//! and reads the clock on waking:
//! - wake-up latency `L_k = t_wake,k − t_k` (cyclictest's figure);
//! - period jitter `J_k = |(t_wake,k − t_wake,k−1) − T|`, the same figure
//!   the pipeline's control output is judged by;
//! - a deadline miss when a wake-up comes after the next deadline
//!   (`L_k ≥ T`): those periods are skipped, as cyclictest does, and each
//!   skipped period counts as one miss.
//!
//! All cores run at once (like `cyclictest -a -t`), so the baseline sees the
//! same machine the pipeline does.
//!
//! **Host stall probe** (after `hwlatdetect`): then one thread per core
//! spins on the clock ([`crate::rt::stall`]) and counts the gaps the host
//! made, by what the guest kernel saw of them, at the stage budgets.
//!
//! [`timer`] runs the baseline; [`report`] puts the pipeline's figures
//! beside it; [`probe`] the stall probe's.

pub mod probe;
mod report;
mod timer;

pub use probe::{StallRow, THRESHOLDS_US};
pub use report::{baseline_entries, JitterEntry, JitterReport, PipelineInfo};
pub use timer::{timer_baseline, CoreTimer, TimerConfig};

#[cfg(test)]
mod tests {
    use super::report::*;
    use super::timer::*;
    use crate::latency::LatencyError;
    use crate::rt::LatencyHist;
    use std::sync::atomic::AtomicBool;
    use std::time::Duration;

    #[test]
    fn the_timer_wakes_once_per_period_never_early() {
        let cfg = TimerConfig {
            rate_hz: 500.0,
            duration: Duration::from_millis(1300),
            cores: vec![0],
            fifo: None,
            hdr_logs: true,
        };
        let stop = AtomicBool::new(false);
        let r = timer_baseline(&cfg, &stop).unwrap();
        assert_eq!(r.len(), 1);
        let c = &r[0];
        // Every period either woke once or was counted as missed.
        assert_eq!(c.wakeups + c.misses, 650, "{} + {}", c.wakeups, c.misses);
        assert_eq!(c.period_jitter.count() + 1, c.wakeups);
        // Never before the deadline (the histogram records ≥ 1 ns).
        assert!(c.wake.count() == c.wakeups);
        // One interval per second, written off the timer thread, plus the
        // last partial one.
        assert_eq!(c.wake_log.as_ref().unwrap().intervals(), 2);
        assert_eq!(c.jitter_log.as_ref().unwrap().intervals(), 2);
        let (merged, per_core) = baseline_entries(&cfg, &r);
        assert_eq!(merged.latency.count, c.wakeups);
        assert_eq!(per_core[0].name, "timer-core0");
        assert_eq!(merged.budget_us, Some(2_000.0));
    }

    #[test]
    fn a_raised_stop_flag_ends_the_baseline_at_once() {
        let cfg = TimerConfig {
            rate_hz: 1000.0,
            duration: Duration::from_secs(3600),
            cores: vec![0],
            fifo: None,
            hdr_logs: false,
        };
        let stop = AtomicBool::new(true);
        let r = timer_baseline(&cfg, &stop).unwrap();
        assert_eq!(r[0].wakeups, 0);
    }

    #[test]
    fn ratios_compare_like_with_like() {
        let mut j = LatencyHist::new();
        let mut l = LatencyHist::new();
        for v in 1..=100u64 {
            j.record(v * 1_000);
            l.record(v * 10_000);
        }
        let base = JitterEntry::new("timer", None, &j, &j, 0, None);
        let e = JitterEntry::new("control", None, &l, &l, 3, Some(1000.0)).with_ratios(&base);
        let r50 = e.ratio_p50.unwrap();
        let r99 = e.ratio_p99.unwrap();
        assert!(
            (r50 - 10.0).abs() < 0.02 && (r99 - 10.0).abs() < 0.02,
            "{r50} {r99}"
        );
        assert!((e.latency_ratio_p99.unwrap() - 10.0).abs() < 0.02);
        let empty =
            JitterEntry::new("x", None, &LatencyHist::new(), &l, 0, None).with_ratios(&base);
        assert_eq!(empty.ratio_p50, None);
        assert!(empty.latency_ratio_p50.is_some());
    }

    #[test]
    fn bad_settings_are_typed_errors() {
        let ok = TimerConfig {
            rate_hz: 1000.0,
            duration: Duration::from_secs(1),
            cores: vec![0],
            fifo: Some(80),
            hdr_logs: false,
        };
        assert!(ok.validate().is_ok());
        for bad in [
            TimerConfig {
                rate_hz: 0.0,
                ..ok.clone()
            },
            TimerConfig {
                rate_hz: f64::NAN,
                ..ok.clone()
            },
            TimerConfig {
                duration: Duration::ZERO,
                ..ok.clone()
            },
            TimerConfig {
                cores: vec![],
                ..ok.clone()
            },
            TimerConfig {
                cores: vec![4096],
                ..ok.clone()
            },
            TimerConfig {
                fifo: Some(0),
                ..ok.clone()
            },
        ] {
            assert!(
                matches!(bad.validate(), Err(LatencyError::BadArg(_))),
                "{bad:?}"
            );
        }
    }
}
