//! Policies survive the text format bit for bit and bad files are refused
//! with their line; the simulator matches an exactly evaluated policy and
//! the solver's bounds within its standard error, and is reproducible.

mod common;

use beliefbus_pomdp::simulate::horizon;
use beliefbus_pomdp::{
    simulate, simulate_plan, solve, AlphaPolicy, PolicyError, SimulateError, SimulateOptions,
    SolveOptions,
};
use common::*;

fn sim(runs: usize, seed: u64, threads: usize) -> SimulateOptions {
    SimulateOptions {
        runs,
        seed,
        threads,
        precision: 1e-4,
    }
}

#[test]
fn policy_text_round_trips_and_bad_files_name_their_line() {
    let p = load_own("noisy_two_state.pomdp");
    let sol = solve(&p, &SolveOptions::default(), |_| {}).unwrap();
    let text = sol.policy.to_text();
    assert_eq!(AlphaPolicy::from_text("x", &text).unwrap(), sol.policy);
    let path = std::env::temp_dir().join(format!("beliefbus-pomdp-{}.policy", std::process::id()));
    sol.policy.write(&path).unwrap();
    let back = AlphaPolicy::read(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!(back, sol.policy);

    let bad = [
        ("alpha 1\n", 1, "beliefbus-alpha 1"),
        (
            "beliefbus-alpha 1\nstates 2 actions 3\n",
            2,
            "states N actions A vectors K",
        ),
        (
            "beliefbus-alpha 1\nstates 2 actions 3 vectors 1\n3 0 1\n",
            3,
            "action index below 3",
        ),
        (
            "beliefbus-alpha 1\nstates 2 actions 3 vectors 1\n# c\n1 0\n",
            4,
            "expected 2 values",
        ),
        (
            "beliefbus-alpha 1\nstates 2 actions 3 vectors 1\n1 0 x\n",
            3,
            "finite numbers",
        ),
        (
            "beliefbus-alpha 1\nstates 2 actions 3 vectors 2\n1 0 1\n",
            3,
            "header says 2 vectors",
        ),
    ];
    for (text, line, says) in bad {
        match AlphaPolicy::from_text("p.policy", text) {
            Err(e @ PolicyError::Format { line: l, .. }) => {
                assert_eq!(l, line, "{e}");
                assert!(e.to_string().contains(says), "{e}");
                assert!(
                    e.to_string().starts_with(&format!("p.policy:{line}:")),
                    "{e}"
                );
            }
            other => panic!("{text:?}: {other:?}"),
        }
    }
    // a policy for another model is refused
    let other = load_own("two_state_mdp.pomdp");
    assert!(matches!(
        simulate(&other, &sol.policy, &sim(10, 1, 1)),
        Err(SimulateError::Policy(PolicyError::Mismatch { .. }))
    ));
}

#[test]
fn simulation_matches_an_exactly_evaluated_policy() {
    // "always stay" on the fully observed problem: V = (I − γT)^{-1} R
    let p = load_own("two_state_mdp.pomdp");
    let g = p.discount;
    let t = |s: usize, s2: usize| p.trans[0].get(s, s2);
    let (a, b, c, d) = (
        1.0 - g * t(0, 0),
        -g * t(0, 1),
        -g * t(1, 0),
        1.0 - g * t(1, 1),
    );
    let det = a * d - b * c;
    let (r0, r1) = (p.reward[0][0], p.reward[0][1]);
    let v = [(d * r0 - b * r1) / det, (a * r1 - c * r0) / det];
    let exact = p.start[0] * v[0] + p.start[1] * v[1];
    let stay = AlphaPolicy {
        n_states: 2,
        n_actions: 2,
        vectors: vec![v.to_vec()],
        actions: vec![0],
    };
    let r = simulate(&p, &stay, &sim(20_000, 7, 2)).unwrap();
    assert!(
        (r.mean - exact).abs() < 4.0 * r.std_err,
        "{} ± {} vs exact {exact}",
        r.mean,
        r.std_err
    );
    assert!(r.std_err > 0.0 && r.std_err < 0.05);
    let (lo, hi) = p.reward_range();
    let tail = g.powi(r.horizon as i32) * lo.abs().max(hi.abs()) / (1.0 - g);
    assert!(
        tail <= 1e-4 && tail * g.powi(-1) > 1e-4,
        "H = {} is not the first horizon below the precision",
        r.horizon
    );
    assert_eq!(r.horizon, horizon(&p, 1e-4));
}

#[test]
fn simulation_is_reproducible_and_independent_of_threads() {
    let p = load_own("noisy_two_state.pomdp");
    let sol = solve(&p, &SolveOptions::default(), |_| {}).unwrap();
    let one = simulate(&p, &sol.policy, &sim(500, 3, 1)).unwrap();
    let two = simulate(&p, &sol.policy, &sim(500, 3, 2)).unwrap();
    let other = simulate(&p, &sol.policy, &sim(500, 4, 2)).unwrap();
    assert_eq!(one, two);
    assert_ne!(one.mean, other.mean);
    assert!(matches!(
        simulate(&p, &sol.policy, &sim(1, 3, 1)),
        Err(SimulateError::Runs(1))
    ));
}

#[test]
fn solved_policies_earn_their_bounds_in_simulation() {
    for (p, runs) in [
        (load_own("noisy_two_state.pomdp"), 20_000),
        (load_shared("tiger.95.POMDP"), 20_000),
        (load_shared("RockSample_4_4.pomdp"), 4_000),
    ] {
        let sol = solve(&p, &SolveOptions::default(), |_| {}).unwrap();
        assert!(sol.converged);
        let r = simulate(&p, &sol.policy, &sim(runs, 11, 2)).unwrap();
        // the policy's value lies in [lower, V*] ⊂ [lower, upper]
        assert!(
            r.mean >= sol.lower - 3.0 * r.std_err && r.mean <= sol.upper + 3.0 * r.std_err,
            "simulated {} ± {} vs bounds [{}, {}]",
            r.mean,
            r.std_err,
            sol.lower,
            sol.upper
        );
    }
}

/// Tiger and 4x3 solved to 1e-3: the lower bound's own controller (the plan
/// of the vector best at b₀, followed without a belief) earns V̲(b₀) within
/// 3 standard errors — the bound is the value of a policy the solver can
/// execute, not an estimate — and the greedy policy does at least as well.
#[test]
fn the_lower_bounds_controller_earns_the_lower_bound() {
    for name in ["tiger.95.POMDP", "4x3.95.POMDP"] {
        let p = load_shared(name);
        let sol = solve(
            &p,
            &SolveOptions {
                precision: 1e-3,
                threads: 1,
                ..Default::default()
            },
            |_| {},
        )
        .unwrap();
        let opts = sim(20_000, 3, 2);
        let r = simulate_plan(&p, &sol, &opts).unwrap();
        assert!((r.vector_value - sol.lower).abs() < 1e-9, "{name}");
        let z = (r.result.mean - sol.lower) / r.result.std_err;
        assert!(z.abs() < 3.0, "{name}: {r:?} vs lower {}", sol.lower);
        let g = simulate(&p, &sol.policy, &opts).unwrap();
        assert!(g.mean > sol.lower - 3.0 * g.std_err, "{name}: {g:?}");
    }
    let p = load_shared("tiger.95.POMDP");
    let sol = solve(&p, &SolveOptions::default(), |_| {}).unwrap();
    assert!(matches!(
        simulate_plan(&p, &sol, &sim(1, 0, 1)),
        Err(SimulateError::Runs(1))
    ));
}
