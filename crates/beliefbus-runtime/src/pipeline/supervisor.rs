//! Supervision policy of `beliefbus run`: when a stage process dies or
//! hangs, whether and when it is restarted, and the seeded chaos schedule of
//! `--chaos`. The launcher ([`super::launcher`]) applies these decisions; the
//! decisions themselves are pure and unit-tested here.
//!
//! Per stage, `[stages.<name>.restart]` ([`RestartPolicy`]):
//! - `on = "failure"` (default): restart after a crash (exit status ≠ 0, or
//!   killed by a signal) or a hang; a stage that exits 0 on its own ends the
//!   run (it decided to stop). `"always"`: restart after any exit.
//!   `"never"`: any exit or hang ends the run.
//! - Backoff: the n-th consecutive restart waits
//!   `d_n = min(backoff_ms · 2^(n−1), max_backoff_ms)`; an incarnation that
//!   lived at least `reset_after_s` resets n to 1 (so an occasional crash
//!   restarts after `backoff_ms`, a crash loop slows down exponentially).
//! - `max_restarts` (absent: unlimited) bounds the restarts of the stage
//!   over the run; one more failure ends the run.
//! - Hang detection by heartbeat: every stage publishes its statistics
//!   every `run.stats_period_s` from its loop's tick (also when it has no
//!   input). A stage whose last report is older than `heartbeat_timeout_ms`
//!   (default `max(5 · stats_period_s, 2 s)`) is counted as a heartbeat
//!   miss, killed with SIGKILL and handled like a crash.
//!
//! Chaos (`beliefbus run --chaos SECONDS`): kill times form a Poisson
//! process of mean interval SECONDS (exponential gaps
//! `Δ = −SECONDS · ln(1 − U)`, U uniform on [0, 1)) drawn from
//! `rng::stream(seed, CHAOS_STREAM)`; each kill picks one running stage
//! uniformly from the allowed ones and sends it SIGKILL.

use crate::rng::{self, SimRng};
use rand::RngExt;
use std::time::Duration;

pub use crate::config::restart::{PolicyError, RestartOn, RestartPolicy};

/// Why a stage incarnation ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Death {
    /// Exited with this status code.
    Exit(i32),
    /// Killed by this signal (not by the supervisor for a hang).
    Signal(i32),
    /// Missed its heartbeat deadline; the supervisor killed it.
    Hang,
}

impl Death {
    /// A clean exit.
    pub fn is_clean(self) -> bool {
        self == Death::Exit(0)
    }

    /// Report name of the cause (`exit 1`, `signal 9`, `hang`).
    pub fn describe(self) -> String {
        match self {
            Death::Exit(c) => format!("exit {c}"),
            Death::Signal(s) => format!("signal {s}"),
            Death::Hang => "hang".into(),
        }
    }
}

/// What to do about a death.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    /// Restart after this delay; the value is the consecutive-restart count.
    Restart { after: Duration, consecutive: u32 },
    /// End the run, with this reason.
    GiveUp(GiveUpReason),
}

/// Why the supervisor ends the run instead of restarting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GiveUpReason {
    /// `on = "never"`.
    PolicyNever,
    /// A clean exit under `on = "failure"`.
    CleanExit,
    /// `max_restarts` used up.
    TooManyRestarts,
    /// The stage exited with [`crate::stage::FATAL_EXIT`]: restarting it
    /// would resume the same broken state.
    Fatal,
}

/// Restart bookkeeping of one stage.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RestartState {
    /// Restarts so far over the run.
    pub restarts: u32,
    /// Consecutive restarts (reset by a long-lived incarnation).
    pub consecutive: u32,
}

impl RestartState {
    /// Decide about a death of an incarnation that lived `lived`.
    pub fn decide(&mut self, p: &RestartPolicy, death: Death, lived: Duration) -> Decision {
        if death == Death::Exit(crate::stage::FATAL_EXIT) {
            return Decision::GiveUp(GiveUpReason::Fatal);
        }
        match p.on {
            RestartOn::Never => return Decision::GiveUp(GiveUpReason::PolicyNever),
            RestartOn::Failure if death.is_clean() => {
                return Decision::GiveUp(GiveUpReason::CleanExit)
            }
            _ => {}
        }
        if p.max_restarts.is_some_and(|m| self.restarts >= m) {
            return Decision::GiveUp(GiveUpReason::TooManyRestarts);
        }
        if lived >= Duration::from_secs_f64(p.reset_after_s) {
            self.consecutive = 0;
        }
        self.consecutive += 1;
        self.restarts += 1;
        Decision::Restart {
            after: p.backoff(self.consecutive),
            consecutive: self.consecutive,
        }
    }
}

/// RNG stream id of the chaos schedule (mixed with the seed).
pub const CHAOS_STREAM: u64 = 0x0043_4841_4F53; // "CHAOS"

/// The seeded kill schedule of `--chaos`.
#[derive(Debug)]
pub struct Chaos {
    mean_s: f64,
    rng: SimRng,
}

impl Chaos {
    /// Kills at mean interval `mean_s` seconds, seeded.
    pub fn new(mean_s: f64, seed: u64) -> Self {
        Self {
            mean_s,
            rng: rng::stream(seed, CHAOS_STREAM),
        }
    }

    /// The gap to the next kill: exponential with mean `mean_s`.
    pub fn next_gap(&mut self) -> Duration {
        let u: f64 = self.rng.random();
        Duration::from_secs_f64(-self.mean_s * (1.0 - u).ln())
    }

    /// Pick one of `n` candidates uniformly (None if there are none).
    pub fn pick(&mut self, n: usize) -> Option<usize> {
        (n > 0).then(|| self.rng.random_range(0..n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(d: Duration) -> f64 {
        d.as_secs_f64() * 1e3
    }

    #[test]
    fn backoff_doubles_up_to_the_cap_and_resets_after_a_long_life() {
        let p = RestartPolicy {
            backoff_ms: 10.0,
            max_backoff_ms: 75.0,
            reset_after_s: 1.0,
            ..RestartPolicy::default()
        };
        let mut s = RestartState::default();
        let short = Duration::from_millis(100);
        let mut delays = Vec::new();
        for _ in 0..5 {
            match s.decide(&p, Death::Signal(9), short) {
                Decision::Restart { after, .. } => delays.push(ms(after)),
                d => panic!("{d:?}"),
            }
        }
        let want = [10.0, 20.0, 40.0, 75.0, 75.0];
        for (d, w) in delays.iter().zip(want) {
            assert!((d - w).abs() < 1e-6, "{delays:?}");
        }
        // A long-lived incarnation starts a new series.
        match s.decide(&p, Death::Exit(3), Duration::from_secs(2)) {
            Decision::Restart { after, consecutive } => {
                assert_eq!(consecutive, 1);
                assert!((ms(after) - 10.0).abs() < 1e-6);
            }
            d => panic!("{d:?}"),
        }
        assert_eq!(s.restarts, 6);
    }

    #[test]
    fn policies_decide_per_cause() {
        let mut s = RestartState::default();
        let t = Duration::ZERO;
        let failure = RestartPolicy::default();
        assert_eq!(
            s.decide(&failure, Death::Exit(0), t),
            Decision::GiveUp(GiveUpReason::CleanExit)
        );
        assert!(matches!(
            s.decide(&failure, Death::Hang, t),
            Decision::Restart { .. }
        ));
        let always = RestartPolicy {
            on: RestartOn::Always,
            ..RestartPolicy::default()
        };
        assert!(matches!(
            s.decide(&always, Death::Exit(0), t),
            Decision::Restart { .. }
        ));
        let never = RestartPolicy {
            on: RestartOn::Never,
            ..RestartPolicy::default()
        };
        assert_eq!(
            s.decide(&never, Death::Signal(9), t),
            Decision::GiveUp(GiveUpReason::PolicyNever)
        );
        let capped = RestartPolicy {
            max_restarts: Some(1),
            ..RestartPolicy::default()
        };
        let mut c = RestartState::default();
        assert!(matches!(
            c.decide(&capped, Death::Signal(9), t),
            Decision::Restart { .. }
        ));
        assert_eq!(
            c.decide(&capped, Death::Signal(9), t),
            Decision::GiveUp(GiveUpReason::TooManyRestarts)
        );
        // A stage that reports an unrecoverable state (the plant's state
        // went non-finite) is never restarted into it, whatever the policy.
        let always = RestartPolicy {
            on: RestartOn::Always,
            ..RestartPolicy::default()
        };
        assert_eq!(
            RestartState::default().decide(&always, Death::Exit(crate::stage::FATAL_EXIT), t),
            Decision::GiveUp(GiveUpReason::Fatal)
        );
    }

    #[test]
    fn heartbeat_default_scales_with_the_stats_period() {
        let p = RestartPolicy::default();
        assert_eq!(p.heartbeat_timeout(1.0), Duration::from_secs(5));
        assert_eq!(p.heartbeat_timeout(0.1), Duration::from_secs(2));
        let q = RestartPolicy {
            heartbeat_timeout_ms: Some(750.0),
            ..p
        };
        assert_eq!(q.heartbeat_timeout(1.0), Duration::from_millis(750));
    }

    #[test]
    fn validation_names_the_key() {
        let bad = RestartPolicy {
            max_backoff_ms: 1.0,
            backoff_ms: 5.0,
            ..RestartPolicy::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "max_backoff_ms");
        let bad = RestartPolicy {
            heartbeat_timeout_ms: Some(0.0),
            ..RestartPolicy::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "heartbeat_timeout_ms");
        assert!(RestartPolicy::default().validate().is_ok());
    }

    #[test]
    fn chaos_gaps_are_exponential_with_the_mean_and_seeded() {
        let mut a = Chaos::new(2.0, 7);
        let mut b = Chaos::new(2.0, 7);
        let n = 20_000;
        let gaps: Vec<f64> = (0..n).map(|_| a.next_gap().as_secs_f64()).collect();
        for g in &gaps[..50] {
            assert_eq!(*g, b.next_gap().as_secs_f64());
        }
        let mean = gaps.iter().sum::<f64>() / n as f64;
        // Exponential: sd = mean, so the sample mean's sd is 2/√n ≈ 0.014.
        assert!((mean - 2.0).abs() < 5.0 * 2.0 / (n as f64).sqrt(), "{mean}");
        // P(gap > mean) = e⁻¹.
        let frac = gaps.iter().filter(|g| **g > 2.0).count() as f64 / n as f64;
        assert!((frac - (-1f64).exp()).abs() < 0.02, "{frac}");
        let mut counts = [0usize; 5];
        for _ in 0..5000 {
            counts[a.pick(5).unwrap()] += 1;
        }
        assert!(counts.iter().all(|&c| c > 850 && c < 1150), "{counts:?}");
        assert_eq!(a.pick(0), None);
    }
}
