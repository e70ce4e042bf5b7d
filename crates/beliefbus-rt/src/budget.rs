//! A stage's compute budget: every processed message's compute time goes
//! into a histogram, and a time above the budget counts as a deadline miss
//! (DESIGN.md: "misses are counted and reported, never hidden").
//!
//! Lateness: a message is *released* when its input was
//! published (the plant: when its tick was due). Its deadline is release +
//! budget, so its lateness is `(t_end − t_release) − budget` — negative when
//! early. The response time `t_end − t_release` (queueing + compute) goes
//! into a histogram (lateness percentiles are its percentiles minus the
//! budget), and a positive lateness counts the message as late.
//!
//! Who missed: a miss is wall-clock time, which also runs while the stage is
//! not on its CPU. When the stage marks where a message's work starts
//! ([`Budget::start`]), a miss whose own thread CPU time stayed within the
//! budget is also counted as *preempted*: the overrun was time taken from
//! the stage (another thread, the kernel, the host's hypervisor), not work
//! it did. The rest are its own overruns. A message without a start mark
//! measures from the previous mark, which can only make its CPU time larger:
//! the split never calls an own overrun preempted.
//!
//! Taken by whom: a preempted miss during which the thread was never
//! switched out (its voluntary + involuntary context-switch count did not
//! move, [`thread_switches`]) lost its time without the guest kernel
//! scheduling anything else in its place: the time went to interrupt
//! handlers or to the hypervisor that runs the virtual CPU. Those are
//! counted as *host* misses; the run's per-core steal and interrupt time
//! (`crate::host`) say which of the two. A miss with a switch was taken by
//! another thread of this machine (a higher-priority stage on the core, a
//! kernel thread) and is the pipeline's own business.

use super::clock::{thread_cpu_ns, thread_switches};
use super::hist::LatencyHist;

/// Compute-time accounting against a budget.
#[derive(Clone, Debug)]
pub struct Budget {
    budget_ns: u64,
    misses: u64,
    preempted: u64,
    host: u64,
    /// Thread CPU time at the last [`Budget::start`] (0: never marked).
    cpu_start_ns: u64,
    /// The thread's context switches at the last [`Budget::start`].
    switches_start: u64,
    compute: LatencyHist,
    response: LatencyHist,
    late: u64,
}

impl Budget {
    /// A budget of `budget_ns` per message (0: no budget, nothing misses).
    pub fn new(budget_ns: u64) -> Self {
        Self {
            budget_ns,
            misses: 0,
            preempted: 0,
            host: 0,
            cpu_start_ns: 0,
            switches_start: 0,
            compute: LatencyHist::new(),
            response: LatencyHist::new(),
            late: 0,
        }
    }

    /// Mark the start of a message's work for the preempted/overrun and
    /// host split (a thread-CPU clock read and a context-switch count).
    pub fn start(&mut self) {
        self.cpu_start_ns = thread_cpu_ns();
        self.switches_start = thread_switches();
    }

    /// Record one message that started at `start_ns` and finished at
    /// `end_ns`; returns true if it missed the budget.
    pub fn record(&mut self, start_ns: u64, end_ns: u64) -> bool {
        let dt = end_ns.saturating_sub(start_ns);
        self.compute.record(dt);
        let miss = self.budget_ns > 0 && dt > self.budget_ns;
        self.misses += miss as u64;
        if miss && self.cpu_start_ns > 0 {
            let cpu = thread_cpu_ns().saturating_sub(self.cpu_start_ns);
            match classify(self.budget_ns, cpu, self.switches_start, thread_switches()) {
                MissKind::Overrun => {}
                MissKind::Preempted => self.preempted += 1,
                MissKind::Host => {
                    self.preempted += 1;
                    self.host += 1;
                }
            }
        }
        miss
    }

    /// Record one message released at `release_ns` (its input's publish
    /// time), started at `start_ns` and finished at `end_ns`: compute time
    /// as [`Budget::record`], and its response time `end − release` (a
    /// release of 0 or after the end is unknown and not recorded). Returns
    /// true if the compute time missed the budget.
    pub fn record_released(&mut self, release_ns: u64, start_ns: u64, end_ns: u64) -> bool {
        let miss = self.record(start_ns, end_ns);
        if release_ns > 0 && release_ns <= end_ns {
            let r = end_ns - release_ns;
            self.response.record(r);
            self.late += (self.budget_ns > 0 && r > self.budget_ns) as u64;
        }
        miss
    }

    /// Messages whose response time exceeded the budget (positive lateness).
    pub fn late(&self) -> u64 {
        self.late
    }

    /// The response-time histogram (release → end).
    pub fn response(&self) -> &LatencyHist {
        &self.response
    }

    /// The budget in ns.
    pub fn budget_ns(&self) -> u64 {
        self.budget_ns
    }

    /// Messages over budget so far.
    pub fn misses(&self) -> u64 {
        self.misses
    }

    /// Of [`Budget::misses`], those whose own CPU time stayed within the
    /// budget: time was taken from the stage, it did not overrun.
    pub fn preempted(&self) -> u64 {
        self.preempted
    }

    /// Of [`Budget::preempted`], those during which the thread was never
    /// switched out: the time went to interrupts or the hypervisor.
    pub fn host(&self) -> u64 {
        self.host
    }

    /// The compute-time histogram.
    pub fn compute(&self) -> &LatencyHist {
        &self.compute
    }
}

/// Who a deadline miss belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MissKind {
    /// The stage's own CPU time exceeded the budget.
    Overrun,
    /// Within budget on the CPU, but the thread was switched out: another
    /// thread of this machine ran in its place.
    Preempted,
    /// Within budget on the CPU and never switched out: interrupts or the
    /// hypervisor took the time.
    Host,
}

/// Classify a miss from the thread's CPU time over the message and its
/// context-switch counts before and after (an unknown count, `u64::MAX`,
/// never classes a miss as the host's).
pub fn classify(
    budget_ns: u64,
    cpu_ns: u64,
    switches_before: u64,
    switches_after: u64,
) -> MissKind {
    if cpu_ns > budget_ns {
        MissKind::Overrun
    } else if switches_before == switches_after && switches_after != u64::MAX {
        MissKind::Host
    } else {
        MissKind::Preempted
    }
}

#[cfg(test)]
mod tests {
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
        assert!(b.record(t0, crate::clock::now_ns()));
        assert_eq!((b.misses(), b.preempted()), (1, 1));
        // The sleep switched the thread out: this machine, not the host.
        assert_eq!(b.host(), 0);
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
}
