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
//!
//! Which misses, when: the most recent misses are kept in a fixed ring
//! ([`MissLog`], [`Budget::miss_log`]) with their start time on the
//! stage's clock, wall and thread CPU time, context switches and kind;
//! older ones are counted, never silently lost. Each also carries the
//! thread's page faults (minor and major) over the message: the start mark
//! already makes the `getrusage` call that counts the switches, and the
//! same call returns the faults, so they cost nothing more there. Only a
//! miss reads the thread's clocks at the end: the on-time path stays a
//! histogram record and a compare.
//!
//! Warm-up apart from steady state: a miss whose work started within the
//! first `warmup_ns` after the stage's first recorded message
//! ([`Budget::with_warmup`]) is also counted as a *warm-up* miss
//! ([`Budget::warmup_misses`]). That splits the total, it never hides a
//! miss: [`Budget::misses`] counts every one.

use super::clock::{thread_cpu_ns, thread_usage, ThreadUsage};
use super::hist::LatencyHist;
pub use super::miss_log::MissKind;
use super::miss_log::{Faults, Miss, MissLog};

/// Compute-time accounting against a budget.
#[derive(Clone, Debug)]
pub struct Budget {
    budget_ns: u64,
    misses: u64,
    preempted: u64,
    host: u64,
    /// Thread CPU time at the last [`Budget::start`] (0: never marked).
    cpu_start_ns: u64,
    /// The thread's switches and faults at the last [`Budget::start`].
    usage_start: ThreadUsage,
    compute: LatencyHist,
    response: LatencyHist,
    late: u64,
    /// The most recent misses.
    log: MissLog,
    /// Length of the warm-up (ns from the first recorded message).
    warmup_ns: u64,
    /// Start of the first recorded message (`u64::MAX`: none yet).
    first_ns: u64,
    /// Misses that started in the warm-up.
    warmup_misses: u64,
}

impl Budget {
    /// A budget of `budget_ns` per message (0: no budget, nothing misses).
    pub fn new(budget_ns: u64) -> Self {
        Self::with_warmup(budget_ns, 0)
    }

    /// A budget of `budget_ns` per message whose misses in the first
    /// `warmup_ns` after the first recorded message also count as warm-up
    /// misses.
    pub fn with_warmup(budget_ns: u64, warmup_ns: u64) -> Self {
        Self {
            budget_ns,
            misses: 0,
            preempted: 0,
            host: 0,
            cpu_start_ns: 0,
            usage_start: ThreadUsage::UNKNOWN,
            compute: LatencyHist::new(),
            response: LatencyHist::new(),
            late: 0,
            log: MissLog::new(),
            warmup_ns,
            first_ns: u64::MAX,
            warmup_misses: 0,
        }
    }

    /// Mark the start of a message's work for the preempted/overrun and
    /// host split and the miss log's faults (a thread-CPU clock read and
    /// one `getrusage`).
    pub fn start(&mut self) {
        self.start_at(thread_cpu_ns(), thread_usage());
    }

    /// [`Budget::start`] with the thread's CPU clock and usage given.
    fn start_at(&mut self, cpu_ns: u64, usage: ThreadUsage) {
        self.cpu_start_ns = cpu_ns;
        self.usage_start = usage;
    }

    /// Record one message that started at `start_ns` and finished at
    /// `end_ns` (both on the stage's clock); returns true if it missed the
    /// budget.
    pub fn record(&mut self, start_ns: u64, end_ns: u64) -> bool {
        self.record_probed(start_ns, end_ns, || (thread_cpu_ns(), thread_usage()))
    }

    /// [`Budget::record`] with `now` giving the thread's CPU clock and
    /// usage at the end (read only for a miss).
    fn record_probed(
        &mut self,
        start_ns: u64,
        end_ns: u64,
        now: impl FnOnce() -> (u64, ThreadUsage),
    ) -> bool {
        let dt = end_ns.saturating_sub(start_ns);
        self.first_ns = self.first_ns.min(start_ns);
        self.compute.record(dt);
        let miss = self.budget_ns > 0 && dt > self.budget_ns;
        if miss {
            self.count_miss(start_ns, dt, now);
        }
        miss
    }

    /// Classify, count and log a miss of wall time `wall_ns` that started
    /// at `start_ns`.
    #[cold]
    fn count_miss(
        &mut self,
        start_ns: u64,
        wall_ns: u64,
        now: impl FnOnce() -> (u64, ThreadUsage),
    ) {
        self.misses += 1;
        if start_ns < self.first_ns.saturating_add(self.warmup_ns) {
            self.warmup_misses += 1;
        }
        let (kind, cpu_ns, switches, faults) = if self.cpu_start_ns > 0 {
            let (cpu_now, u) = now();
            let u0 = self.usage_start;
            let cpu = cpu_now.saturating_sub(self.cpu_start_ns);
            let kind = classify(self.budget_ns, cpu, u0.switches, u.switches);
            let known = u0 != ThreadUsage::UNKNOWN && u != ThreadUsage::UNKNOWN;
            let switches = known.then(|| u.switches.saturating_sub(u0.switches));
            let faults = known.then(|| Faults {
                minor: u.minor_faults.saturating_sub(u0.minor_faults),
                major: u.major_faults.saturating_sub(u0.major_faults),
            });
            (kind, Some(cpu), switches, faults)
        } else {
            // No mark: nothing says the time was taken from the stage.
            (MissKind::Overrun, None, None, None)
        };
        match kind {
            MissKind::Overrun => {}
            MissKind::Preempted => self.preempted += 1,
            MissKind::Host => {
                self.preempted += 1;
                self.host += 1;
            }
        }
        self.log.push(Miss {
            start_ns,
            wall_ns,
            cpu_ns,
            switches,
            faults,
            kind,
        });
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

    /// Of [`Budget::misses`], those whose work started in the warm-up (the
    /// first `warmup_ns` after the first recorded message); the rest,
    /// `misses − warmup_misses`, are the steady state's.
    pub fn warmup_misses(&self) -> u64 {
        self.warmup_misses
    }

    /// The warm-up's length in ns ([`Budget::with_warmup`]).
    pub fn warmup_ns(&self) -> u64 {
        self.warmup_ns
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

    /// The most recent misses (oldest first) and how many were pushed out:
    /// [`Budget::misses`] = listed + [`MissLog::overwritten`].
    pub fn miss_log(&self) -> &MissLog {
        &self.log
    }
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
#[path = "budget_tests.rs"]
mod tests;
