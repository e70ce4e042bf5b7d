//! The open-loop plans' vectors against independent answers: a dense
//! linear solve of each plan's controller, the MDP's values above them,
//! and the closed-form value of walking to a goal and declaring.

use super::*;
use crate::model::SparseRows;
use crate::solver::dense_eval::exact_value;
use crate::solver::graph::Controller;
use crate::solver::{lower, solve, upper, SolveOptions};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn random_rows(rng: &mut StdRng, n: usize, m: usize, support: usize) -> SparseRows {
    let rows = (0..n)
        .map(|_| {
            let mut d = vec![0.0; m];
            for _ in 0..support {
                d[rng.random_range(0..m)] += rng.random_range(0.05..1.0);
            }
            let t: f64 = d.iter().sum();
            d.iter_mut().for_each(|x| *x /= t);
            d
        })
        .collect::<Vec<_>>();
    SparseRows::from_dense(&rows)
}

fn random_pomdp(seed: u64, ns: usize, na: usize, no: usize) -> Pomdp {
    let mut rng = StdRng::seed_from_u64(seed);
    let trans = (0..na).map(|_| random_rows(&mut rng, ns, ns, 2)).collect();
    let obs = (0..na).map(|_| random_rows(&mut rng, ns, no, 2)).collect();
    let reward = (0..na)
        .map(|_| (0..ns).map(|_| rng.random_range(-5.0..5.0)).collect())
        .collect();
    Pomdp::new(0.9, vec![1.0 / ns as f64; ns], trans, obs, reward).expect("valid")
}

/// The plan as a controller: prefix nodes, then a node repeating the
/// final action, every observation to the next node.
fn controller(p: &Pomdp, plan: &OpenLoopPlan) -> Controller {
    let no = p.n_obs();
    let t = plan.prefix.len();
    let mut action = plan.prefix.clone();
    action.push(plan.final_action);
    let next = (0..=t)
        .flat_map(|k| std::iter::repeat_n((k + 1).min(t) as u32, no))
        .collect();
    Controller {
        action,
        next,
        values: Vec::new(),
    }
}

#[test]
fn each_vector_is_its_plans_exact_value_and_below_the_mdp() {
    for seed in 0..6 {
        let p = random_pomdp(seed, 7, 3, 3);
        let blind = lower::blind_vectors(&p, 1e-12, 100_000);
        let q = upper::mdp_q(&p, 1e-12, 100_000, None);
        let plans = open_loop_plans(&p, &q, &blind, 12, None);
        for plan in &plans {
            assert!(!plan.prefix.is_empty() && plan.prefix.len() <= 12);
            let exact = &exact_value(&p, &controller(&p, plan))[0];
            for s in 0..p.n_states() {
                let mdp = (0..p.n_actions()).map(|a| q[a][s]).fold(f64::MIN, f64::max);
                assert!(
                    plan.alpha[s] <= exact[s] + 1e-9 && plan.alpha[s] >= exact[s] - 1e-8,
                    "seed {seed}: α {} vs the plan's value {}",
                    plan.alpha[s],
                    exact[s]
                );
                assert!(plan.alpha[s] <= mdp + 1e-9, "above V_MDP");
            }
        }
        // Distinct plans only.
        for (i, a) in plans.iter().enumerate() {
            for b in &plans[i + 1..] {
                assert!(a.prefix != b.prefix || a.final_action != b.final_action);
            }
        }
    }
}

/// A deterministic line 0..n with a goal g: left, right, declare (+10 at
/// g, −10 elsewhere, then an absorbing state paying 0); moves cost 0.
/// Blind policies declare at once or never, so from s they are worth at
/// most 10 only at g; the open-loop plan walks |s − g| steps and declares:
/// γ^{|s−g|}·10, the MDP's optimum.
fn line(n: usize, g: usize, gamma: f64) -> Pomdp {
    let end = n;
    let ns = n + 1;
    let step = |s: usize, a: usize| match (s, a) {
        (s, _) if s == end => end,
        (s, 0) => s.saturating_sub(1),
        (s, 1) => (s + 1).min(n - 1),
        _ => end,
    };
    let trans = (0..3)
        .map(|a| {
            SparseRows::from_rows(
                (0..ns).map(|s| vec![(step(s, a) as u32, 1.0)]).collect(),
                ns,
            )
        })
        .collect();
    let obs = (0..3)
        .map(|_| SparseRows::from_rows(vec![vec![(0, 1.0)]; ns], 1))
        .collect();
    let mut reward = vec![vec![0.0; ns]; 3];
    for s in 0..n {
        reward[2][s] = if s == g { 10.0 } else { -10.0 };
    }
    let mut start = vec![0.0; ns];
    start[0] = 1.0;
    Pomdp::new(gamma, start, trans, obs, reward).expect("valid")
}

#[test]
fn walking_to_the_goal_and_declaring_is_found_from_every_state() {
    let (n, g, gamma) = (9, 6, 0.9);
    let p = line(n, g, gamma);
    let blind = lower::blind_vectors(&p, 1e-12, 100_000);
    let q = upper::mdp_q(&p, 1e-12, 100_000, None);
    let plans = open_loop_plans(&p, &q, &blind, 20, None);
    for s in 0..n {
        let best = plans.iter().map(|pl| pl.alpha[s]).fold(f64::MIN, f64::max);
        let want = 10.0 * gamma.powi((s as i32 - g as i32).abs());
        if s == g {
            // Declaring at once is the blind policy; no plan improves it.
            assert!(best <= want + 1e-9);
        } else {
            assert!((best - want).abs() < 1e-9, "from {s}: {best} vs {want}");
        }
    }
    // The solver's lower bound at b₀ = e_0 starts there: closed before
    // any trial could tighten it.
    let opts = SolveOptions {
        threads: 1,
        precision: 1e-6,
        open_loop_horizon: 20,
        ..Default::default()
    };
    let mut first = None;
    let sol = solve(&p, &opts, |r| {
        first.get_or_insert(r.lower);
    })
    .expect("solves");
    let want = 10.0 * gamma.powi(g as i32);
    let got = first.expect("a report");
    // The blind leaf is iterated to the solver's tolerance (1e-9 here).
    assert!(
        got <= want + 1e-9 && got >= want - 1e-7,
        "first V̲(b₀) {got}, want {want}"
    );
    assert!(sol.lower <= want + 1e-9 && sol.upper >= want - 1e-9);
    // Without the plans the first report is the blind bound (≤ 0 here).
    let blind_only = SolveOptions {
        open_loop_horizon: 0,
        ..opts
    };
    let mut first = None;
    solve(&p, &blind_only, |r| {
        first.get_or_insert(r.lower);
    })
    .expect("solves");
    assert!(first.expect("a report") <= 0.0);
}
