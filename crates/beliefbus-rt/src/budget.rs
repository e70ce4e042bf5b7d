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

use super::hist::LatencyHist;

/// Compute-time accounting against a budget.
#[derive(Clone, Debug)]
pub struct Budget {
    budget_ns: u64,
    misses: u64,
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
            compute: LatencyHist::new(),
            response: LatencyHist::new(),
            late: 0,
        }
    }

    /// Record one message that started at `start_ns` and finished at
    /// `end_ns`; returns true if it missed the budget.
    pub fn record(&mut self, start_ns: u64, end_ns: u64) -> bool {
        let dt = end_ns.saturating_sub(start_ns);
        self.compute.record(dt);
        let miss = self.budget_ns > 0 && dt > self.budget_ns;
        self.misses += miss as u64;
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

    /// The compute-time histogram.
    pub fn compute(&self) -> &LatencyHist {
        &self.compute
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
}
