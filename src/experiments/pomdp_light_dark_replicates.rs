//! Independent solves of one size summarised: the 2-D rows of every solve
//! (`solve` = 0, 1, …; chains from seeds seed, seed + 1, …) grouped by
//! their state count, with the mean, the sample standard deviation and the
//! range of the chain reward, the continuous value and the goal fraction
//! over the solves. One solve's standard error measures only its
//! simulation; the spread between solves (other samples, another stopping
//! point of a wall-clock budget) is what says whether one size is better
//! than another.

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
    let mut out = Vec::new();
    for n in sizes {
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
        for key in METRICS {
            let v: Vec<f64> = group.iter().filter_map(|r| r.get(key)).collect();
            if v.len() < 2 {
                continue;
            }
            let (mean, sd, lo, hi) = spread(&v);
            row = row
                .num(key, mean)
                .num(&format!("{key}_sd"), sd)
                .num(&format!("{key}_min"), lo)
                .num(&format!("{key}_max"), hi);
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
    }
}
