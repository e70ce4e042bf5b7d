//! V̲(b₀) is the exact value of the plan behind it: checked against a dense
//! linear solve of that plan's controller, on solves stopped with the gap
//! still open (where the backed-up vector and the plan's value differ).

use super::dense_eval::exact_value;
use super::graph::{self, Controller};
use super::{solve, SolveOptions};
use crate::model::Pomdp;
use std::time::Duration;

fn noisy_two_state() -> Pomdp {
    crate::parse_str(
        "noisy_two_state.pomdp",
        include_str!("../../tests/data/noisy_two_state.pomdp"),
    )
    .expect("parses")
}

fn dot(v: &[f64], b: &[f64]) -> f64 {
    v.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[test]
fn lower_bound_at_b0_is_its_plans_exact_value() {
    let p = noisy_two_state();
    for precision in [2.0, 0.5, 0.1, 1e-3] {
        let opts = SolveOptions {
            precision,
            time_limit: Some(Duration::from_secs(60)),
            threads: 1,
            ..Default::default()
        };
        let sol = solve(&p, &opts, |_| {}).expect("solves");
        let (k, v) = sol.policy.best_dense(&p.start);
        assert!((v - sol.lower).abs() < 1e-12, "V̲(b₀) is the policy's value");
        let (_, action, next) = graph::reachable(&sol.plan, sol.plan_nodes[k]);
        let c = Controller {
            values: Vec::new(),
            action,
            next,
        };
        let exact = dot(&exact_value(&p, &c)[0], &p.start);
        // The certificate keeps the reported value at or below the plan's
        // exact value, within the evaluation tolerance.
        let tol = precision * (1.0 - p.discount) * 1e-2 / (1.0 - p.discount);
        assert!(
            sol.lower <= exact + 1e-9 && sol.lower >= exact - 2.0 * tol - 1e-9,
            "precision {precision}: V̲(b₀) {} vs plan value {exact}",
            sol.lower
        );
        assert!(sol.lower <= sol.upper + 1e-9);
    }
}

/// Spreading the trials changes where they go, not what the bounds mean:
/// with and without it the solve converges and the two intervals overlap
/// (the exact value lies in both; `tests/solver.rs` checks it against
/// exact value iteration with the default, spread, rule).
#[test]
fn spread_and_plain_trials_reach_overlapping_intervals() {
    let p = noisy_two_state();
    let run = |spread_trials| {
        let opts = SolveOptions {
            precision: 1e-4,
            time_limit: Some(Duration::from_secs(60)),
            threads: 1,
            spread_trials,
            ..Default::default()
        };
        solve(&p, &opts, |_| {}).expect("solves")
    };
    let (a, b) = (run(true), run(false));
    for s in [&a, &b] {
        assert!(s.converged && s.upper - s.lower <= 1e-4 && s.upper >= s.lower);
    }
    assert!(a.lower <= b.upper + 1e-12 && b.lower <= a.upper + 1e-12);
}
