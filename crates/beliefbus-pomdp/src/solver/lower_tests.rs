//! [`LowerBound::best`] over the transposed store against scoring every
//! vector with [`SparseBelief::dot`], through additions, dominance
//! removals and pruning.

use super::*;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn empty(n_obs: usize) -> LowerBound {
    LowerBound {
        vectors: Vec::new(),
        actions: Vec::new(),
        nodes: Vec::new(),
        graph: PlanGraph::new(n_obs),
        by_state: Vec::new(),
        cap: 0,
    }
}

/// A belief on a random support of 1..=`max_support` of `ns` states.
fn random_belief(rng: &mut StdRng, ns: usize, max_support: usize) -> SparseBelief {
    let m = rng.random_range(1..=max_support);
    let mut d = vec![0.0; ns];
    for _ in 0..m {
        d[rng.random_range(0..ns)] += rng.random_range(0.01..1.0);
    }
    let total: f64 = d.iter().sum();
    d.iter_mut().for_each(|x| *x /= total);
    SparseBelief::from_dense(&d)
}

/// The reference: first index of the largest `α·b`, one vector at a time.
fn brute(lb: &LowerBound, b: &SparseBelief) -> (usize, f64) {
    let mut best = (0, f64::NEG_INFINITY);
    for (k, v) in lb.vectors.iter().enumerate() {
        let x = b.dot(v);
        if x > best.1 {
            best = (k, x);
        }
    }
    best
}

fn check(lb: &LowerBound, beliefs: &[SparseBelief]) {
    for b in beliefs {
        let (k, v) = lb.best(b);
        let (k0, v0) = brute(lb, b);
        assert_eq!(k, k0, "index at {b:?}");
        assert_eq!(v.to_bits(), v0.to_bits(), "value at {b:?}");
    }
}

#[test]
fn best_matches_scoring_each_vector_through_adds_removals_and_pruning() {
    let ns = 37;
    let mut rng = StdRng::seed_from_u64(17);
    let mut lb = empty(3);
    let beliefs: Vec<SparseBelief> = (0..200).map(|_| random_belief(&mut rng, ns, 6)).collect();
    let mut removed = 0;
    // Vectors from a few shared offsets plus noise: many tie-free
    // crossings, and some dominate earlier ones (exercising removal).
    for round in 0..500 {
        let lift = round as f64 * 0.002;
        let v: Vec<f64> = (0..ns)
            .map(|s| (s as f64 * 0.37 + round as f64).sin() + lift + rng.random_range(0.0..0.5))
            .collect();
        let before = lb.vectors.len();
        let node = lb.graph.push_loop(round % 3);
        if lb.add(v, round % 3, node) {
            removed += before + 1 - lb.vectors.len();
        }
        if round % 50 == 0 {
            check(&lb, &beliefs);
        }
    }
    assert!(
        removed > 0,
        "no vector was ever dominated: removal untested"
    );
    assert!(
        lb.vectors.len() > BEST_CHUNK,
        "one chunk only: chunking untested"
    );
    check(&lb, &beliefs);
    // An exact copy of a vector: the tie goes to the lower index.
    let dup = lb.vectors[3].clone();
    lb.vectors.push(dup);
    lb.actions.push(0);
    lb.nodes.push(0);
    lb.rebuild(lb.cap.max(lb.vectors.len()));
    check(&lb, &beliefs);
    lb.vectors.pop();
    lb.actions.pop();
    lb.nodes.pop();
    lb.rebuild(lb.cap);
    let n = lb.vectors.len();
    lb.prune(beliefs[..40].iter());
    assert!(lb.vectors.len() < n, "pruning kept everything: untested");
    check(&lb, &beliefs);
    for round in 0..100 {
        let v: Vec<f64> = (0..ns).map(|_| rng.random_range(0.0..2.5)).collect();
        let node = lb.graph.push_loop(0);
        lb.add(v, 0, node);
        if round % 10 == 0 {
            check(&lb, &beliefs);
        }
    }
    check(&lb, &beliefs);
}

/// Every vector of Γ is at most the exact value of the plan its node
/// stands for (after redirects), checked by a dense linear solve.
fn assert_vectors_are_plan_values(p: &Pomdp, lb: &LowerBound) {
    use crate::solver::dense_eval::exact_value;
    use crate::solver::graph::{reachable, Controller};
    for (k, v) in lb.vectors.iter().enumerate() {
        let (_, action, next) = reachable(&lb.graph, lb.nodes[k]);
        let c = Controller {
            values: Vec::new(),
            action,
            next,
        };
        let exact = &exact_value(p, &c)[0];
        for (s, (a, x)) in v.iter().zip(exact).enumerate() {
            assert!(
                *a <= x + 1e-9,
                "vector {k} state {s}: {a} above its plan's {x}"
            );
        }
    }
}

/// A second, lower vector for a node that already holds one (the
/// solver's final evaluation of the plan behind V̲(b₀), cut short by its
/// deadline so its certificate shift is large) can be dominated by
/// another vector. The node must then keep its own plan: redirected to
/// the dominating vector's plan, the vector it already holds would claim
/// more than that plan is worth.
#[test]
fn a_dominated_second_vector_does_not_redirect_a_protected_node() {
    let p = crate::parse_str(
        "noisy_two_state.pomdp",
        include_str!("../../tests/data/noisy_two_state.pomdp"),
    )
    .expect("parses");
    let mut lb = LowerBound::blind(&p, 1e-13, 100_000);
    let blind_nodes = lb.nodes.clone();
    // A one-step conditional plan (act, then a blind policy chosen per
    // observation) that no blind vector dominates.
    let mut found = None;
    'search: for a in 0..p.n_actions() {
        for &j0 in &blind_nodes {
            for &j1 in &blind_nodes {
                let next = [j0, j1];
                let w: Vec<Vec<f64>> = next
                    .iter()
                    .map(|&j| {
                        lb.vectors[lb.nodes.iter().position(|&n| n == j).expect("blind")].clone()
                    })
                    .collect();
                let alpha: Vec<f64> = (0..p.n_states())
                    .map(|s| {
                        let cont: Vec<f64> = (0..p.n_states())
                            .map(|s2| (0..p.n_obs()).map(|o| p.obs[a].get(s2, o) * w[o][s2]).sum())
                            .collect();
                        p.backup_at(a, s, &cont)
                    })
                    .collect();
                if lb.add_plan(alpha, a, &next) {
                    found = Some(*lb.nodes.last().expect("added"));
                    break 'search;
                }
            }
        }
    }
    let node = found.expect("a conditional plan better than every blind policy somewhere");
    assert_vectors_are_plan_values(&p, &lb);
    // Its plan's value with a large certificate shift: dominated by a
    // blind vector.
    let k = lb.nodes.iter().position(|&n| n == node).expect("kept");
    let low: Vec<f64> = lb.vectors[k].iter().map(|x| x - 100.0).collect();
    assert!(
        lb.dominating(&low).is_some(),
        "the shifted vector is dominated"
    );
    let protect = std::collections::HashSet::from([node]);
    assert!(!lb.add_protecting(low, lb.actions[k], node, &protect));
    assert_eq!(
        lb.graph.resolve(node),
        node,
        "the protected node was redirected"
    );
    assert_vectors_are_plan_values(&p, &lb);
}
