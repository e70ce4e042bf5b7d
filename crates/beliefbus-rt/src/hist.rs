//! Latency and compute-time histograms (HdrHistogram, 3 significant digits,
//! 1 ns … 100 s). The counts array is allocated once at construction, so
//! recording never allocates; values beyond the range saturate.

use hdrhistogram::Histogram;

/// Highest trackable value: 100 s in ns.
const HIGH_NS: u64 = 100_000_000_000;

/// A histogram of nanosecond durations.
#[derive(Clone, Debug)]
pub struct LatencyHist {
    h: Histogram<u64>,
}

impl Default for LatencyHist {
    fn default() -> Self {
        Self::new()
    }
}

impl LatencyHist {
    /// An empty histogram covering 1 ns … 100 s at 3 significant digits.
    pub fn new() -> Self {
        let mut h =
            Histogram::new_with_bounds(1, HIGH_NS, 3).expect("static histogram bounds are valid");
        h.auto(false);
        Self { h }
    }

    /// Record one duration (0 is recorded as 1 ns; beyond 100 s saturates).
    pub fn record(&mut self, ns: u64) {
        self.h.saturating_record(ns.max(1));
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.h.len()
    }

    /// Value at quantile `q` ∈ [0, 1] in ns (0 when empty).
    pub fn quantile(&self, q: f64) -> u64 {
        if self.h.is_empty() {
            0
        } else {
            self.h.value_at_quantile(q)
        }
    }

    /// Largest value recorded (0 when empty).
    pub fn max(&self) -> u64 {
        if self.h.is_empty() {
            0
        } else {
            self.h.max()
        }
    }

    /// Add another histogram's counts.
    pub fn merge(&mut self, other: &LatencyHist) {
        // Same bounds on both sides, so adding cannot fail.
        let _ = self.h.add(&other.h);
    }

    /// Forget every value.
    pub fn reset(&mut self) {
        self.h.reset();
    }

    /// The underlying HdrHistogram (for exporting logs).
    pub fn inner(&self) -> &Histogram<u64> {
        &self.h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_uniform_sequence() {
        let mut h = LatencyHist::new();
        for v in 1..=10_000u64 {
            h.record(v * 1_000); // 1 µs … 10 ms
        }
        assert_eq!(h.count(), 10_000);
        // 3 significant digits: relative error ≤ 0.1 %.
        for (got, want) in [
            (h.quantile(0.5), 5_000_000.0),
            (h.quantile(0.9), 9_000_000.0),
            (h.quantile(0.99), 9_900_000.0),
            (h.quantile(0.999), 9_990_000.0),
            (h.max(), 10_000_000.0),
        ] {
            assert!((got as f64 - want).abs() / want < 1e-3, "{got} vs {want}");
        }
    }

    #[test]
    fn empty_and_saturating() {
        let mut h = LatencyHist::new();
        assert_eq!((h.count(), h.quantile(0.5), h.max()), (0, 0, 0));
        h.record(0);
        h.record(u64::MAX);
        assert_eq!(h.count(), 2);
        assert!(h.max() >= HIGH_NS / 2);
    }

    #[test]
    fn merge_adds_counts() {
        let mut a = LatencyHist::new();
        let mut b = LatencyHist::new();
        a.record(10);
        b.record(1_000);
        b.record(2_000);
        a.merge(&b);
        assert_eq!(a.count(), 3);
        assert!(a.max() >= 1_999);
    }
}
