//! Independent solves of one size summarised: the 2-D rows of every solve
//! (`solve` = 0, 1, …; chains from seeds seed, seed + 1, …) grouped by
//! their state count, with the mean, the sample standard deviation and the
//! range of the chain reward, the continuous value and the goal fraction
//! over the solves. One solve's standard error measures only its
//! simulation; the spread between solves (other samples, another stopping
//! point of a wall-clock budget) is what says whether one size is better
//! than another. Each metric's `_se` is sd/√k over the k solves, and
//! `_step` (± `_step_se`) the mean over the solves of the difference from
//! the previous size *of the same solve* (the chain of size n contains
//! that of the previous size; the evaluation's seeds are the same), the
//! paired comparison that says whether growing the chain lost anything.

use super::{ExperimentReport, Row};

const METRICS: [&str; 4] = ["reward", "continuous", "goal_frac", "lower_b0"];

/// Appends one `replicates` row per 2-D size that has at least two solves.
pub fn summarise(rep: &mut ExperimentReport) {
    let mut sizes: Vec<u64> = Vec::new();
    let rows: Vec<&Row> = rep
        .results
        .iter()
        .filter(|r| {
            r.method == "chain-pomdp"
                && r.metrics.get("problem").and_then(|v| v.as_str()) == Some("2-D")
                && r.get("solve").is_some()
        })
        .collect();
    for r in &rows {
        if let Some(n) = r.get("states") {
            if !sizes.contains(&(n as u64)) {
                sizes.push(n as u64);
            }
        }
    }
    // The chain grows: the previous size is the next smaller one.
    sizes.sort_unstable();
    let mut out = Vec::new();
    for &n in &sizes {
        let group: Vec<&&Row> = rows
            .iter()
            .filter(|r| r.get("states") == Some(n as f64))
            .collect();
        if group.len() < 2 {
            continue;
        }
        let mut row = Row::new("replicates")
            .text("problem", "2-D")
            .int("states", n)
            .int("solves", group.len() as u64);
        let k = sizes.iter().position(|&m| m == n).unwrap_or(0);
        let prev_n = k.checked_sub(1).map(|j| sizes[j]);
        for key in METRICS {
            let v: Vec<f64> = group.iter().filter_map(|r| r.get(key)).collect();
            if v.len() < 2 {
                continue;
            }
            let (mean, sd, lo, hi) = spread(&v);
            row = row
                .num(key, mean)
                .num(&format!("{key}_sd"), sd)
                .num(&format!("{key}_se"), sd / (v.len() as f64).sqrt())
                .num(&format!("{key}_min"), lo)
                .num(&format!("{key}_max"), hi);
            // The same solve's previous size, matched by `solve`.
            let steps: Vec<f64> = prev_n
                .map(|pn| {
                    group
                        .iter()
                        .filter_map(|r| {
                            let here = r.get(key)?;
                            let solve = r.get("solve")?;
                            let there = rows
                                .iter()
                                .find(|q| {
                                    q.get("states") == Some(pn as f64)
                                        && q.get("solve") == Some(solve)
                                })?
                                .get(key)?;
                            Some(here - there)
                        })
                        .collect()
                })
                .unwrap_or_default();
            if steps.len() >= 2 {
                let (m, sd, _, _) = spread(&steps);
                row = row
                    .num(&format!("{key}_step"), m)
                    .num(&format!("{key}_step_se"), sd / (steps.len() as f64).sqrt());
            }
        }
        out.push(row);
    }
    rep.results.extend(out);
}

/// Mean, sample standard deviation, minimum and maximum (≥ 2 values).
fn spread(v: &[f64]) -> (f64, f64, f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (mean, var.sqrt(), lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_of_one_size_are_summarised_by_mean_sd_and_range() {
        let mut rep = ExperimentReport::new("t");
        for (s, n, r, c) in [(0, 75, 1.0, -2.0), (1, 75, 3.0, 2.0), (0, 150, 5.0, 0.0)] {
            rep.results.push(
                Row::new("chain-pomdp")
                    .text("problem", "2-D")
                    .int("states", n)
                    .int("solve", s)
                    .num("reward", r)
                    .num("continuous", c),
            );
        }
        summarise(&mut rep);
        let s: Vec<&Row> = rep
            .results
            .iter()
            .filter(|r| r.method == "replicates")
            .collect();
        // 150 has a single solve: no summary.
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].get("states"), Some(75.0));
        assert_eq!(s[0].get("reward"), Some(2.0));
        assert_eq!(s[0].get("reward_sd"), Some(2f64.sqrt()));
        assert_eq!(s[0].get("continuous_min"), Some(-2.0));
        assert_eq!(s[0].get("continuous_max"), Some(2.0));
        assert_eq!(s[0].get("goal_frac"), None);
        assert_eq!(s[0].get("reward_se"), Some(1.0));
        // The first size has no previous one.
        assert_eq!(s[0].get("reward_step"), None);
    }

    #[test]
    fn steps_pair_each_solve_with_its_own_previous_size() {
        let mut rep = ExperimentReport::new("t");
        // solve 0: 10 → 13 (+3); solve 1: 20 → 21 (+1); solve 2: 30 → 35 (+5).
        // Listed out of order: the pairing is by `solve`, not by position.
        for (s, n, r) in [
            (2, 150, 35.0),
            (0, 75, 10.0),
            (1, 75, 20.0),
            (2, 75, 30.0),
            (0, 150, 13.0),
            (1, 150, 21.0),
        ] {
            rep.results.push(
                Row::new("chain-pomdp")
                    .text("problem", "2-D")
                    .int("states", n)
                    .int("solve", s)
                    .num("reward", r),
            );
        }
        summarise(&mut rep);
        let row = rep
            .results
            .iter()
            .find(|r| r.method == "replicates" && r.get("states") == Some(150.0))
            .expect("150 summarised");
        // Steps 3, 1, 5: mean 3, sd 2, s.e. 2/√3.
        assert_eq!(row.get("reward_step"), Some(3.0));
        let se = row.get("reward_step_se").expect("step s.e.");
        assert!((se - 2.0 / 3f64.sqrt()).abs() < 1e-12, "{se}");
    }
}
