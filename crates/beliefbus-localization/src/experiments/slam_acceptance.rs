//! The `slam` experiment's acceptance lines: the paper's comparisons of
//! Table 6 as paired differences over the same data sets.

use super::params::mean_se;
use super::slam::RunMetrics;

/// The acceptance comparisons, paired over the data sets.
pub fn acceptance(methods: &[(&str, usize)], per: &[Vec<RunMetrics>]) -> Vec<String> {
    let idx = |name: &str, m: usize| methods.iter().position(|&x| x == (name, m));
    let mean = |i: usize| mean_se(&per[i].iter().map(|x| x.error_pct).collect::<Vec<_>>()).0;
    let paired = |a: usize, b: usize| {
        let d: Vec<f64> = per[a]
            .iter()
            .zip(&per[b])
            .map(|(x, y)| x.error_pct - y.error_pct)
            .collect();
        mean_se(&d)
    };
    let mut out = vec![];
    let ekf = idx("ekf", 1);
    for (a, b, paper) in [
        (
            ("implicit", 100),
            ("fastslam2", 400),
            "paper: 2.98% vs 4.83%",
        ),
        (("implicit", 100), ("ekf", 1), "paper: 2.98% vs 3.89%"),
        (("fastslam2", 500), ("ekf", 1), "paper: 4.71% vs 3.89%"),
        (
            ("implicit-refine", 100),
            ("fastslam2", 400),
            "refined re-observations; paper: 2.98% vs 4.83%",
        ),
        (
            ("implicit-refine", 100),
            ("ekf", 1),
            "refined re-observations; paper: 2.98% vs 3.89%",
        ),
        (
            ("implicit-rb", 100),
            ("fastslam2", 400),
            "variant, not in the paper",
        ),
        (
            ("implicit-rb", 100),
            ("ekf", 1),
            "variant, not in the paper",
        ),
        (
            ("fastslam1", 1000),
            ("fastslam2", 500),
            "paper: 8.78% vs 4.71%",
        ),
    ] {
        if let (Some(i), Some(j)) = (idx(a.0, a.1), idx(b.0, b.1)) {
            let (d, se) = paired(i, j);
            out.push(format!(
                "{} at {}: {:.3}% vs {} at {}: {:.3}% (paired difference {d:.3} ± {se:.3}; {paper})",
                a.0,
                a.1,
                mean(i),
                b.0,
                b.1,
                mean(j)
            ));
        }
    }
    let best = |name: &str| {
        (0..methods.len())
            .filter(|&k| methods[k].0 == name)
            .min_by(|&a, &b| mean(a).total_cmp(&mean(b)))
    };
    let mut line = String::from("best error per method:");
    for name in [
        "implicit",
        "implicit-refine",
        "implicit-rb",
        "fastslam1",
        "fastslam2",
    ] {
        if let Some(b) = best(name) {
            line += &format!(" {name} {:.3}% (M = {})", mean(b), methods[b].1);
        }
    }
    if let Some(e) = ekf {
        line += &format!(" ekf {:.3}%", mean(e));
    }
    out.push(line);
    out
}
