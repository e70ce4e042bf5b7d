//! The side-by-side printout of Tables I/II: at each σ our cost (± s.e.)
//! next to the paper's, the relative difference, the deviation above the
//! full-observation policy (ours vs the paper's percentages), the paired
//! differences CE − ours and CE-MLE − ours on common random numbers with
//! their standard errors, the ranking ours ≤ CE ≤ CE-MLE in both, and
//! greedy's ratio to ours.

use super::paper::{Protocol, METHODS};
use super::report::{Report, Row};

fn find<'a>(rows: &'a [Row], method: &str, sigma: f64) -> Option<&'a Row> {
    rows.iter()
        .find(|r| r.method == method && r.get("sigma").is_some_and(|s| (s - sigma).abs() < 1e-9))
}

fn ranking(c: [f64; 3]) -> &'static str {
    if c[0] <= c[1] && c[1] <= c[2] {
        "yes"
    } else {
        "no"
    }
}

/// The table as text.
pub fn side_by_side(protocol: Protocol, rep: &Report) -> String {
    let title = match protocol {
        Protocol::Average => "Table I (average cost per period)",
        Protocol::Discounted { .. } => "Table II (discounted total cost)",
    };
    let mut out = format!("{title}: ours ± s.e. | paper | ours/paper − 1\n");
    out.push_str(&format!("{:>5}", "sigma"));
    for m in METHODS {
        out.push_str(&format!(" | {:>17} {:>8} {:>6}", m, "paper", "diff%"));
    }
    out.push_str(" | dev% ours/paper | ce−ours ± s.e. | ce_mle−ours ± s.e. | ours<=ce<=ce_mle ours/paper | greedy/ours\n");
    let sigmas: Vec<f64> = rep
        .results
        .iter()
        .filter(|r| r.method == "ours")
        .filter_map(|r| r.get("sigma"))
        .collect();
    let (mut within, mut total) = (0, 0);
    let mut worst: f64 = 0.0;
    // The paired deviation above the full-observation run: the paper's
    // parenthesised figure, free of the run's common offset.
    let (mut dev_within, mut dev_total) = (0, 0);
    let mut dev_worst: f64 = 0.0;
    for s in sigmas {
        out.push_str(&format!("{s:>5.1}"));
        let mut ours = [f64::NAN; 4];
        let mut theirs = [f64::NAN; 4];
        for (m, name) in METHODS.iter().enumerate() {
            let r = find(&rep.results, name, s);
            let p = find(&rep.paper, name, s);
            let c = r.and_then(|r| r.get("cost")).unwrap_or(f64::NAN);
            let se = r.and_then(|r| r.get("cost_se")).unwrap_or(f64::NAN);
            let pc = p.and_then(|p| p.get("cost")).unwrap_or(f64::NAN);
            ours[m] = c;
            theirs[m] = pc;
            let diff = 100.0 * (c / pc - 1.0);
            out.push_str(&format!(" | {c:>9.3} ± {se:>5.3} {pc:>8.3} {diff:>+6.2}"));
            if m == 0 && pc.is_finite() {
                total += 1;
                worst = worst.max(diff.abs());
                let tol = if protocol == Protocol::Average {
                    0.5
                } else {
                    2.0
                };
                if diff.abs() <= tol {
                    within += 1;
                }
            }
        }
        let dev = find(&rep.results, "ours", s)
            .and_then(|r| r.get("deviation_pct"))
            .unwrap_or(f64::NAN);
        let pdev = find(&rep.paper, "ours", s)
            .and_then(|r| r.get("deviation_pct"))
            .unwrap_or(f64::NAN);
        if dev.is_finite() && pdev.is_finite() {
            dev_total += 1;
            dev_worst = dev_worst.max((dev - pdev).abs());
            if (dev - pdev).abs() <= 0.5 {
                dev_within += 1;
            }
        }
        let paired = |m: &str| {
            let r = find(&rep.results, m, s);
            let d = r.and_then(|r| r.get("minus_ours")).unwrap_or(f64::NAN);
            let se = r.and_then(|r| r.get("minus_ours_se")).unwrap_or(f64::NAN);
            format!("{d:>+7.3} ± {se:>5.3}")
        };
        out.push_str(&format!(
            " | {dev:>6.2} / {pdev:>6.2} | {} | {} | {:>3} / {:>3} | {:.2}\n",
            paired("ce"),
            paired("ce_mle"),
            ranking([ours[0], ours[1], ours[2]]),
            ranking([theirs[0], theirs[1], theirs[2]]),
            ours[3] / ours[0]
        ));
    }
    let tol = if protocol == Protocol::Average {
        "0.5"
    } else {
        "2"
    };
    out.push_str(&format!("ours within {tol} % of the paper at {within} of {total} sigmas (largest |diff| {worst:.2} %)"));
    if protocol == Protocol::Average {
        out.push_str(&format!("\nours' deviation above the full-observation run on the same random numbers within 0.5 percentage points of the paper's at {dev_within} of {dev_total} sigmas (largest |diff| {dev_worst:.2} points)"));
    }
    out
}
