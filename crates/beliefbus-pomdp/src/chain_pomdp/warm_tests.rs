//! The carried plans against an exact evaluation, and the solver's
//! anytime guarantees from a warm start.

use super::super::tests::{chain, lqg, quadratic, spec};
use super::*;
use crate::chain_pomdp::{build, GaussianObservation};
use crate::solver::dense_eval::exact_value;
use crate::solver::sparse_eval::iterative_value;
use crate::solver::{solve, SolveOptions};

fn best_at(values: &[Vec<f64>], b: &[f64]) -> f64 {
    values
        .iter()
        .map(|v| v.iter().zip(b).map(|(x, y)| x * y).sum::<f64>())
        .fold(f64::NEG_INFINITY, f64::max)
}

struct Pair {
    p1: ChainPomdp,
    s1: crate::Solution,
    p2: ChainPomdp,
}

fn refined_pair() -> Pair {
    let m = lqg(0.3);
    let obs = GaussianObservation {
        model: &m,
        std: vec![0.3],
    };
    let us = [0.0, 0.5, -0.5];
    let opts = SolveOptions {
        precision: 1e-4,
        time_limit: Some(Duration::from_millis(300)),
        threads: 1,
        prune_lower: false,
        ..Default::default()
    };
    let c1 = chain(&m, 20, 4);
    let p1 = build(&c1, &m, &obs, &quadratic, &spec(20, &us, 1.0, 0.2)).expect("p1");
    let s1 = solve(&p1.pomdp, &opts, |_| {}).expect("solve 1");
    let c2 = chain(&m, 40, 5);
    let p2 = build(&c2, &m, &obs, &quadratic, &spec(40, &us, 1.0, 0.2)).expect("p2");
    Pair { p1, s1, p2 }
}

fn carried(pair: &Pair, cap: usize) -> Controller {
    carry_plan(
        &Solved {
            cp: &pair.p1,
            policy: &pair.s1.policy,
            plan: &pair.s1.plan,
            plan_nodes: &pair.s1.plan_nodes,
        },
        &pair.p2,
        cap,
        Duration::from_secs(5),
        1e-11,
    )
}

#[test]
fn carried_plans_are_worth_what_they_claim_and_no_more() {
    let pair = refined_pair();
    let c = carried(&pair, 12);
    assert!(c.len() >= 2, "{} nodes carried", c.len());
    let (exact, e) = iterative_value(&pair.p2.pomdp, &c, None, 1e-13, 1_000_000);
    assert!(e < 1e-10, "evaluation bound {e}");
    for (k, (v, x)) in c.values.iter().zip(&exact).enumerate() {
        for (s, (a, b)) in v.iter().zip(x).enumerate() {
            // A certified lower bound of the controller's value ...
            assert!(
                *a <= b + e + 1e-9,
                "node {k} state {s}: {a} above exact {b}"
            );
            // ... and, converged, equal to it.
            assert!(*a >= b - e - 1e-6, "node {k} state {s}: {a} far below {b}");
        }
    }
}

#[test]
fn warm_lower_bound_at_b0_is_at_least_the_carried_plans_exact_value() {
    let pair = refined_pair();
    let c = carried(&pair, 12);
    let b0 = pair.p2.pomdp.start.clone();
    let (exact, e) = iterative_value(&pair.p2.pomdp, &c, None, 1e-13, 1_000_000);
    assert!(e < 1e-10, "evaluation bound {e}");
    // The carried plans are worth at least this at b₀.
    let exact_b0 = best_at(&exact, &b0) - e;
    let opts = SolveOptions {
        precision: 1e-4,
        time_limit: Some(Duration::from_millis(200)),
        threads: 1,
        prune_lower: false,
        initial_controller: Some(c),
        ..Default::default()
    };
    let mut first = None;
    let warm = solve(&pair.p2.pomdp, &opts, |pr| {
        first.get_or_insert(pr.lower);
    })
    .expect("warm");
    let first = first.expect("a first report");
    assert!(
        first >= exact_b0 - 1e-6,
        "the warm start's first lower bound {first} is below the carried plans' value {exact_b0}"
    );
    assert!(warm.lower >= exact_b0 - 1e-6);
    assert!(warm.lower <= warm.upper + 1e-9);
}

#[test]
fn anytime_bounds_only_tighten_and_the_policy_earns_its_bound() {
    let pair = refined_pair();
    let c = carried(&pair, 64);
    let opts = SolveOptions {
        precision: 1e-5,
        time_limit: Some(Duration::from_millis(400)),
        report_interval: Duration::ZERO,
        threads: 1,
        prune_lower: false,
        initial_controller: Some(c),
        ..Default::default()
    };
    let mut reports = Vec::new();
    let warm = solve(&pair.p2.pomdp, &opts, |pr| reports.push(pr.clone())).expect("warm");
    assert!(reports.len() >= 3, "{} reports", reports.len());
    for w in reports.windows(2) {
        assert!(w[1].lower >= w[0].lower, "lower fell: {w:?}");
        assert!(w[1].upper <= w[0].upper, "upper rose: {w:?}");
        assert!(w[1].lower <= w[1].upper + 1e-9);
    }
    // The greedy policy of a closed plan set earns at least V̲(b₀): more
    // solver time (a larger V̲) cannot make the policy worse than that.
    let sim = crate::SimulateOptions {
        runs: 2000,
        seed: 17,
        precision: 1e-5,
        threads: 1,
    };
    let r = crate::simulate(&pair.p2.pomdp, &warm.policy, &sim).expect("simulate");
    assert!(
        r.mean >= warm.lower - 3.0 * r.std_err,
        "policy earns {} ± {} below its bound {}",
        r.mean,
        r.std_err,
        warm.lower
    );
}

#[test]
fn plans_carried_to_their_own_problem_keep_the_lower_bound() {
    let pair = refined_pair();
    let c = carry_plan(
        &Solved {
            cp: &pair.p1,
            policy: &pair.s1.policy,
            plan: &pair.s1.plan,
            plan_nodes: &pair.s1.plan_nodes,
        },
        &pair.p1,
        usize::MAX,
        Duration::from_secs(5),
        1e-11,
    );
    // Every vector is the value of its plan (dominated continuations only
    // redirected to better ones), so the whole graph is worth at least V̲.
    let b0 = &pair.p1.pomdp.start;
    let v = best_at(&c.values, b0);
    assert!(
        v >= pair.s1.lower - 1e-6,
        "plans worth {v} at b0, the solve claimed {}",
        pair.s1.lower
    );
    assert!(v <= pair.s1.upper + 1e-9);
}

#[test]
fn a_cap_below_the_best_plans_size_still_carries_that_plan_whole() {
    let pair = refined_pair();
    let solved = Solved {
        cp: &pair.p1,
        policy: &pair.s1.policy,
        plan: &pair.s1.plan,
        plan_nodes: &pair.s1.plan_nodes,
    };
    let b0 = &pair.p1.pomdp.start;
    let (k, _) = pair.s1.policy.best_dense(b0);
    let (order, _, _) = crate::solver::graph::reachable(&pair.s1.plan, pair.s1.plan_nodes[k]);
    assert!(order.len() > 2, "the best plan has {} nodes", order.len());
    // Carried onto its own problem with a cap of one node, the best plan
    // is worth exactly what an independent evaluation of its controller
    // gives, which is at least the solve's V̲(b₀) (cut at the cap it would
    // fall to the blind leaf).
    let c = carry_plan(&solved, &pair.p1, 1, Duration::from_secs(5), 1e-11);
    assert!(c.len() > order.len(), "{} nodes carried", c.len());
    let (values, e) = iterative_value(&pair.p1.pomdp, &c, None, 1e-13, 1_000_000);
    assert!(e < 1e-10, "evaluation bound {e}");
    let exact = best_at(&values, b0);
    let v = best_at(&c.values, b0);
    assert!((v - exact).abs() < 1e-6 + e, "certified {v}, exact {exact}");
    assert!(
        exact >= pair.s1.lower - 1e-6 - e,
        "plans worth {exact} at b0, the solve claimed {}",
        pair.s1.lower
    );
}

/// The sweeps the tests above rely on agree with the dense LU solve on
/// the chain's own (small) plans.
#[test]
fn sweeps_agree_with_the_dense_solve_on_small_chain_plans() {
    let pair = refined_pair();
    let mut plans: Vec<(Vec<usize>, Vec<u32>)> = pair
        .s1
        .plan_nodes
        .iter()
        .map(|&node| {
            let (_, action, next) = crate::solver::graph::reachable(&pair.s1.plan, node);
            (action, next)
        })
        .collect();
    plans.sort_by_key(|(a, _)| a.len());
    plans.dedup();
    let mut checked = 0;
    for (action, next) in plans.into_iter().take(3) {
        assert!(action.len() <= 80, "a plan of {} nodes", action.len());
        let c = Controller {
            values: Vec::new(),
            action,
            next,
        };
        let dense = exact_value(&pair.p1.pomdp, &c);
        let (sweeps, e) = iterative_value(&pair.p1.pomdp, &c, None, 1e-13, 1_000_000);
        assert!(e < 1e-10, "evaluation bound {e}");
        for (x, y) in sweeps.iter().flatten().zip(dense.iter().flatten()) {
            assert!((x - y).abs() <= 1e-9, "sweeps {x}, dense {y}, bound {e}");
        }
        checked += 1;
    }
    assert_eq!(checked, 3, "{checked} small plans");
}

/// Every vector `sol` returns is at most the value of the plan its node
/// stands for (after the solve's redirects), evaluated independently over
/// the whole plan graph at once; and V̲(b₀) is the best vector's value.
fn assert_vectors_are_plan_values(p: &crate::Pomdp, sol: &crate::Solution) {
    let roots: Vec<u32> = sol
        .plan_nodes
        .iter()
        .map(|&n| sol.plan.resolve(n))
        .collect();
    let mut local: HashMap<u32, u32> = HashMap::new();
    let mut order: Vec<u32> = Vec::new();
    for &r in &roots {
        if local.contains_key(&r) {
            continue;
        }
        local.insert(r, order.len() as u32);
        order.push(r);
        let mut k = order.len() - 1;
        while k < order.len() {
            for o in 0..p.n_obs() {
                let m = sol.plan.next(order[k], o);
                if let std::collections::hash_map::Entry::Vacant(e) = local.entry(m) {
                    e.insert(order.len() as u32);
                    order.push(m);
                }
            }
            k += 1;
        }
    }
    let local = &local;
    let c = Controller {
        values: Vec::new(),
        action: order.iter().map(|&n| sol.plan.action(n)).collect(),
        next: order
            .iter()
            .flat_map(|&n| (0..p.n_obs()).map(move |o| local[&sol.plan.next(n, o)]))
            .collect(),
    };
    let (values, e) = iterative_value(p, &c, None, 1e-13, 1_000_000);
    assert!(e < 1e-10, "evaluation bound {e}");
    for (k, v) in sol.policy.vectors.iter().enumerate() {
        let x = &values[local[&roots[k]] as usize];
        for (s, (a, b)) in v.iter().zip(x).enumerate() {
            assert!(
                *a <= b + e + 1e-9,
                "vector {k} state {s}: {a} above its plan's {b}"
            );
        }
    }
    let (k, v) = sol.policy.best_dense(&p.start);
    assert!(
        (v - sol.lower).abs() < 1e-12,
        "V̲(b₀) is the best vector's value"
    );
    let x = best_at(&[values[local[&roots[k]] as usize].clone()], &p.start);
    assert!(
        sol.lower <= x + e + 1e-9,
        "V̲(b₀) {} above its plan's {x}",
        sol.lower
    );
}

/// The solves' vectors are plan values: with the default options, and
/// with the open-loop plans (`open_loop_horizon`) in the initial lower
/// bound, where a 300 ms solve leaves the final plan evaluation no time
/// and its shifted value is dominated (the case that once redirected the
/// best vector's node onto a worse plan).
#[test]
fn every_vector_of_a_solve_is_at_most_its_plans_value() {
    let pair = refined_pair();
    assert_vectors_are_plan_values(&pair.p1.pomdp, &pair.s1);
    let opts = SolveOptions {
        precision: 1e-4,
        time_limit: Some(Duration::from_millis(300)),
        threads: 1,
        prune_lower: false,
        open_loop_horizon: 64,
        ..Default::default()
    };
    let sol = solve(&pair.p1.pomdp, &opts, |_| {}).expect("solve with open-loop plans");
    assert_vectors_are_plan_values(&pair.p1.pomdp, &sol);
}
