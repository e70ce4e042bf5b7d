//! Percentile blocks and ratios.
//!
//! A latency distribution is summarised by its count and the values at the
//! quantiles q ∈ {0.5, 0.9, 0.99, 0.999} and its maximum. The q-quantile is
//! the smallest recorded value v with F(v) ≥ q, F the empirical CDF
//! (HdrHistogram's `value_at_quantile`; [`exact_quantile`] computes the same
//! on raw samples). Values come from a [`LatencyHist`] (3 significant
//! digits, so a reported value is within 0.1 % of the exact one).
//!
//! One-way latency of a ping-pong is half the round trip, `(t₁ − t₀)/2`,
//! both stamps taken by the pinging process on CLOCK_MONOTONIC, so no clock
//! offset between processes enters. Ratios compare ours to the baseline at
//! the same quantile: `ratio_q = ours_q / bare_q` (undefined — `None` —
//! when either side has no samples or the baseline value is 0).

use crate::rt::LatencyHist;
use serde::{Deserialize, Serialize};

/// Count and percentiles of a distribution, in microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PctBlock {
    pub count: u64,
    pub p50_us: f64,
    pub p90_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

/// The quantiles of a [`PctBlock`], in order, with their short names.
pub const QUANTILES: [(&str, f64); 4] =
    [("p50", 0.5), ("p90", 0.9), ("p99", 0.99), ("p999", 0.999)];

fn us(ns: u64) -> f64 {
    ns as f64 / 1_000.0
}

impl PctBlock {
    /// The block of a nanosecond histogram.
    pub fn of(h: &LatencyHist) -> Self {
        let p = crate::ipc::Percentiles::from(h);
        Self {
            count: p.count,
            p50_us: us(p.p50_ns),
            p90_us: us(p.p90_ns),
            p99_us: us(p.p99_ns),
            p999_us: us(p.p999_ns),
            max_us: us(p.max_ns),
        }
    }

    /// The values p50, p90, p99, p99.9, max in µs.
    pub fn values(&self) -> [f64; 5] {
        [
            self.p50_us,
            self.p90_us,
            self.p99_us,
            self.p999_us,
            self.max_us,
        ]
    }
}

/// `a / b` when both are positive and finite.
pub fn ratio(a: f64, b: f64) -> Option<f64> {
    (a.is_finite() && b.is_finite() && a > 0.0 && b > 0.0).then(|| a / b)
}

/// Ours / baseline at p50, p90, p99, p99.9 and max (None where undefined,
/// and everywhere when either side is empty).
pub fn ratios(ours: &PctBlock, base: &PctBlock) -> [Option<f64>; 5] {
    let (o, b) = (ours.values(), base.values());
    let mut r = [None; 5];
    if ours.count > 0 && base.count > 0 {
        for i in 0..5 {
            r[i] = ratio(o[i], b[i]);
        }
    }
    r
}

/// One-way latency of a round trip from `t0_ns` to `t1_ns`: half of it.
pub fn one_way_ns(t0_ns: u64, t1_ns: u64) -> u64 {
    t1_ns.saturating_sub(t0_ns) / 2
}

/// The exact q-quantile of `sorted` (ascending): the smallest value v with
/// #{x ≤ v} ≥ ⌈q·n⌉ (at least one sample). None when empty or q ∉ [0, 1].
pub fn exact_quantile(sorted: &[u64], q: f64) -> Option<u64> {
    if sorted.is_empty() || !(0.0..=1.0).contains(&q) {
        return None;
    }
    let n = sorted.len();
    let rank = ((q * n as f64).ceil() as usize).clamp(1, n);
    Some(sorted[rank - 1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SimRng;
    use rand::{RngExt, SeedableRng};

    fn hist(values: impl IntoIterator<Item = u64>) -> LatencyHist {
        let mut h = LatencyHist::new();
        for v in values {
            h.record(v);
        }
        h
    }

    #[test]
    fn known_uniform_samples_give_known_percentiles() {
        // 1 µs … 1000 µs, one sample each.
        let b = PctBlock::of(&hist((1..=1000u64).map(|v| v * 1_000)));
        assert_eq!(b.count, 1000);
        for (got, want) in [
            (b.p50_us, 500.0),
            (b.p90_us, 900.0),
            (b.p99_us, 990.0),
            (b.p999_us, 999.0),
            (b.max_us, 1000.0),
        ] {
            assert!((got - want).abs() / want <= 1e-3, "{got} vs {want}");
        }
    }

    #[test]
    fn a_rare_tail_shows_only_above_its_quantile() {
        // 990 samples of 10 µs and 10 of 1 ms: p99 is still 10 µs (990/1000
        // ≥ 0.99), p99.9 and max are 1 ms.
        let h =
            hist(std::iter::repeat_n(10_000u64, 990).chain(std::iter::repeat_n(1_000_000u64, 10)));
        let b = PctBlock::of(&h);
        assert!((b.p50_us - 10.0).abs() < 0.01);
        assert!((b.p99_us - 10.0).abs() < 0.01, "{}", b.p99_us);
        assert!((b.p999_us - 1000.0).abs() < 1.0, "{}", b.p999_us);
        assert!((b.max_us - 1000.0).abs() < 1.0);
    }

    #[test]
    fn histogram_quantiles_match_exact_quantiles_of_random_samples() {
        // Log-normal-ish latencies around 5 µs with a heavy tail.
        let mut rng = SimRng::seed_from_u64(6);
        let mut xs: Vec<u64> = (0..20_000)
            .map(|_| {
                let z: f64 = rng.random::<f64>() * 4.0 - 1.0;
                (5_000.0 * z.exp()) as u64 + 1
            })
            .collect();
        let h = hist(xs.iter().copied());
        xs.sort_unstable();
        for (_, q) in QUANTILES {
            let exact = exact_quantile(&xs, q).unwrap() as f64;
            let got = h.quantile(q) as f64;
            assert!(
                (got - exact).abs() / exact <= 1e-3,
                "q={q}: {got} vs {exact}"
            );
        }
        let max = *xs.last().unwrap() as f64;
        assert!((h.max() as f64 - max).abs() / max <= 1e-3);
    }

    #[test]
    fn exact_quantile_conventions() {
        let xs = [1u64, 2, 3, 4];
        assert_eq!(exact_quantile(&xs, 0.0), Some(1));
        assert_eq!(exact_quantile(&xs, 0.25), Some(1));
        assert_eq!(exact_quantile(&xs, 0.26), Some(2));
        assert_eq!(exact_quantile(&xs, 0.5), Some(2));
        assert_eq!(exact_quantile(&xs, 1.0), Some(4));
        assert_eq!(exact_quantile(&[], 0.5), None);
        assert_eq!(exact_quantile(&xs, 1.5), None);
    }

    #[test]
    fn ratios_are_per_quantile_and_undefined_without_data() {
        let ours = PctBlock {
            count: 10,
            p50_us: 2.2,
            p90_us: 3.0,
            p99_us: 5.0,
            p999_us: 8.0,
            max_us: 20.0,
        };
        let bare = PctBlock {
            count: 10,
            p50_us: 2.0,
            p90_us: 3.0,
            p99_us: 4.0,
            p999_us: 0.0,
            max_us: 10.0,
        };
        let r = ratios(&ours, &bare);
        assert!((r[0].unwrap() - 1.1).abs() < 1e-12);
        assert_eq!(r[1], Some(1.0));
        assert_eq!(r[2], Some(1.25));
        assert_eq!(r[3], None, "baseline value 0");
        assert_eq!(r[4], Some(2.0));
        let empty = PctBlock::default();
        assert_eq!(ratios(&ours, &empty), [None; 5]);
        assert_eq!(ratios(&empty, &bare), [None; 5]);
        assert_eq!(ratio(1.0, f64::NAN), None);
    }

    #[test]
    fn one_way_is_half_the_round_trip() {
        assert_eq!(one_way_ns(1_000, 1_010), 5);
        assert_eq!(one_way_ns(1_000, 1_011), 5);
        assert_eq!(one_way_ns(1_000, 900), 0);
    }
}
