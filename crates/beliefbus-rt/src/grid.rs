//! Periodic structure in a set of event times: how many pairs of events lie
//! a whole number of periods apart, against what chance gives.
//!
//! For two events at `a < b` the offset `d = b − a` is *aligned* to a
//! period `P` within a tolerance `τ` when `min(d mod P, P − d mod P) < τ`.
//! If the events carry no structure at period `P` (their phases mod `P`
//! independent and uniform), each pair is aligned with probability
//! `p = min(1, 2τ/P)`, so `pairs · p` pairs are expected to be. A source
//! that stops the machine on a fixed grid (a host scheduler's period, a
//! timer) makes the aligned count many times that; comparing it with a
//! period of no meaning (e.g. 97 ms beside 100 ms) guards against any other
//! grid the events sit on (a sensor period: their offsets are then whole
//! sample periods, and every period that is a multiple of it looks
//! aligned).

use serde::{Deserialize, Serialize};

/// The aligned pairs at one period.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alignment {
    pub period_us: f64,
    pub tolerance_us: f64,
    /// Pairs at least the minimum separation apart.
    pub pairs: u64,
    /// Of those, the pairs a whole number of periods apart (± tolerance).
    pub aligned: u64,
    /// What chance gives: `pairs · min(1, 2 · tolerance / period)`.
    pub chance: f64,
}

impl Alignment {
    /// Aligned pairs per pair expected by chance (0 when there are none).
    pub fn ratio(&self) -> f64 {
        if self.chance > 0.0 {
            self.aligned as f64 / self.chance
        } else {
            0.0
        }
    }
}

/// Count the pairs of `times_ns` (any order) at least `min_sep_ns` apart
/// and, of those, the pairs a whole number of `period_ns` apart within
/// `tol_ns`. Quadratic in the number of events: meant for the few thousand
/// a probe or a miss list holds.
pub fn alignment(times_ns: &[u64], period_ns: u64, tol_ns: u64, min_sep_ns: u64) -> Alignment {
    let mut t = times_ns.to_vec();
    t.sort_unstable();
    let period = period_ns.max(1);
    let (mut pairs, mut aligned) = (0u64, 0u64);
    for (i, &a) in t.iter().enumerate() {
        for &b in &t[i + 1..] {
            let d = b - a;
            if d < min_sep_ns {
                continue;
            }
            pairs += 1;
            let r = d % period;
            aligned += (r.min(period - r) < tol_ns) as u64;
        }
    }
    let p = (2.0 * tol_ns as f64 / period as f64).min(1.0);
    Alignment {
        period_us: period_ns as f64 / 1e3,
        tolerance_us: tol_ns as f64 / 1e3,
        pairs,
        aligned,
        chance: pairs as f64 * p,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    const MS: u64 = 1_000_000;

    #[test]
    fn events_on_a_grid_are_all_aligned_at_its_period_and_its_multiples_only() {
        // 40 events at random whole multiples of 100 ms, each moved by up to
        // ±20 µs: every pair is within 40 µs of a multiple of 100 ms.
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let t: Vec<u64> = (0..40)
            .map(|_| rng.random_range(1..600u64) * 100 * MS + rng.random_range(0..40_000u64))
            .collect();
        let a = alignment(&t, 100 * MS, 50_000, 5 * MS);
        assert_eq!(a.aligned, a.pairs);
        assert!(a.pairs > 700, "{a:?}"); // 780 pairs but equal multiples
        assert!((a.chance - a.pairs as f64 * 1e-3).abs() < 1e-9);
        assert!(a.ratio() > 900.0);
        // 97 ms has no relation to the grid: near chance.
        let b = alignment(&t, 97 * MS, 50_000, 5 * MS);
        assert!(
            (b.aligned as f64) < b.chance + 6.0 * b.chance.sqrt() + 3.0,
            "{b:?}"
        );
    }

    #[test]
    fn uniform_events_are_aligned_as_often_as_chance_gives() {
        // 300 events uniform over 60 s: 44 850 pairs, chance 44.9 at
        // 100 ms ± 50 µs. Over 20 seeds the aligned counts stay within a
        // few standard deviations of chance, and their mean within 10 %.
        let mut total = 0u64;
        let mut chance = 0.0;
        for seed in 0..20 {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let t: Vec<u64> = (0..300).map(|_| rng.random_range(0..60_000 * MS)).collect();
            let a = alignment(&t, 100 * MS, 50_000, 5 * MS);
            let sd = a.chance.sqrt();
            assert!(
                (a.aligned as f64 - a.chance).abs() < 5.0 * sd,
                "seed {seed}: {a:?}"
            );
            total += a.aligned;
            chance += a.chance;
        }
        assert!(
            (total as f64 / chance - 1.0).abs() < 0.1,
            "{total} vs {chance}"
        );
    }

    #[test]
    fn the_tolerance_and_the_separation_are_exact_bounds() {
        let p = 100 * MS;
        // Offsets just inside and just outside the tolerance, either side
        // of the grid point.
        let tol = 50_000;
        let a = alignment(&[0, p + tol - 1], p, tol, 0);
        assert_eq!((a.pairs, a.aligned), (1, 1));
        let a = alignment(&[0, p + tol], p, tol, 0);
        assert_eq!((a.pairs, a.aligned), (1, 0));
        let a = alignment(&[0, p - tol + 1], p, tol, 0);
        assert_eq!((a.pairs, a.aligned), (1, 1));
        // Closer than the minimum separation: not a pair at all.
        let a = alignment(&[0, 10, 4 * MS], p, tol, 5 * MS);
        assert_eq!(a.pairs, 0);
        // Order does not matter; a tolerance wider than half the period
        // makes every pair aligned and chance the pair count.
        let a = alignment(&[3 * p, 0, 7 * MS], p, p, 0);
        assert_eq!((a.pairs, a.aligned), (3, 3));
        assert_eq!(a.chance, 3.0);
    }
}
