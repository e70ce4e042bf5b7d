//! A stage's compute budget: every processed message's compute time goes
//! into a histogram, and a time above the budget counts as a deadline miss
//! (DESIGN.md: "misses are counted and reported, never hidden").

use super::hist::LatencyHist;

/// Compute-time accounting against a budget.
#[derive(Clone, Debug)]
pub struct Budget {
    budget_ns: u64,
    misses: u64,
    compute: LatencyHist,
}

impl Budget {
    /// A budget of `budget_ns` per message (0: no budget, nothing misses).
    pub fn new(budget_ns: u64) -> Self {
        Self {
            budget_ns,
            misses: 0,
            compute: LatencyHist::new(),
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
}
