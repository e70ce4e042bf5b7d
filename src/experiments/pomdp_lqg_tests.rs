use super::*;

fn ev(runs: usize, seed: u64) -> Eval {
    Eval {
        alpha: 0.05,
        horizon_s: 30.0,
        sim_dt: 0.002,
        runs,
        seed,
    }
}

#[test]
fn riccati_solves_the_algebraic_equation_and_matches_a_simulated_lqg_controller() {
    let alpha = 0.05;
    let (p, l, j) = riccati(alpha);
    // 2(a−α)P − P² + 1 = 0 with a = −1, b = r = q = 1.
    assert!((2.0 * (-1.0 - alpha) * p - p * p + 1.0).abs() < 1e-12);
    assert!((l - p).abs() < 1e-15);
    // The Kalman + LQR controller decided every 10 ms, simulated on the
    // continuous system: its cost is J* up to Monte-Carlo error, the
    // 10 ms hold and the truncation at 30 s (tail ≤ e^{−3}·0.05).
    let costs = evaluate_lqg(0.01, &ev(300, 3));
    let (m, se) = mean_se(&costs);
    assert!(
        (m - j).abs() < 3.0 * se + 0.004,
        "simulated {m} ± {se} vs Riccati {j}"
    );
}

fn chain_costs(sizes: &[usize], solve_s: f64, runs: usize) -> Vec<(usize, f64, f64)> {
    let mut out = Vec::new();
    refine(sizes, 0.05, 0.1, solve_s, 7, |st| {
        let (m, se) = mean_se(&evaluate(st, &ev(runs, 11)));
        out.push((st.cp.n_chain(), m, se));
        Ok(())
    })
    .expect("refine");
    out
}

fn check_towards_riccati(rows: &[(usize, f64, f64)]) {
    let (_, _, j) = riccati(0.05);
    for w in rows.windows(2) {
        let ((n0, m0, s0), (n1, m1, s1)) = (w[0], w[1]);
        // Cost does not grow with n beyond the 95 % interval of the
        // difference.
        assert!(
            m1 <= m0 + 1.96 * (s0 * s0 + s1 * s1).sqrt(),
            "cost at {n1} states {m1} ± {s1} above cost at {n0} states {m0} ± {s0}"
        );
    }
    for &(n, m, se) in rows {
        // No policy beats the optimum (truncation at 30 s lowers J by
        // at most e^{−3}·0.05).
        assert!(
            m >= j - 3.0 * se - 0.003,
            "{n} states: {m} ± {se} below J* {j}"
        );
    }
}

#[test]
fn lqg_cost_moves_towards_the_riccati_value_as_states_grow_small() {
    let rows = chain_costs(&[20, 80], 1.0, 100);
    check_towards_riccati(&rows);
}

#[test]
#[ignore = "minutes: the table's sizes up to 640 states"]
fn lqg_cost_moves_towards_the_riccati_value_as_states_grow() {
    let rows = chain_costs(&[20, 40, 80, 160, 320, 640], 10.0, 200);
    check_towards_riccati(&rows);
    let (_, _, j) = riccati(0.05);
    let last = rows.last().expect("rows");
    let first = rows[0];
    assert!(last.1 - j < first.1 - j, "no progress towards J*: {rows:?}");
}
