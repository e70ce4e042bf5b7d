//! Value iteration and relative value iteration against exact answers on
//! small MDPs: every deterministic policy evaluated by a linear solve
//! (discounted) or by its stationary distribution (average cost), the best
//! one taken by enumeration.

use beliefbus_projection::mdp::FiniteMdp;
use beliefbus_projection::rng::stream;
use nalgebra::{DMatrix, DVector};
use rand::RngExt;

/// A random dense MDP: costs in [0, 10), rows of positive probabilities.
fn random_mdp(n: usize, na: usize, seed: u64, sparse: bool) -> (Vec<Vec<f64>>, Vec<Vec<Vec<f64>>>) {
    let mut rng = stream(seed, 0);
    let cost = (0..n)
        .map(|_| (0..na).map(|_| 10.0 * rng.random::<f64>()).collect())
        .collect();
    let p = (0..na)
        .map(|_| {
            (0..n)
                .map(|i| {
                    let row: Vec<f64> = (0..n)
                        .map(|j| {
                            let u: f64 = rng.random();
                            // Sparse rows keep their successor i + 1.
                            if sparse && u < 0.4 && j != (i + 1) % n {
                                0.0
                            } else {
                                u + 0.05
                            }
                        })
                        .collect();
                    let t: f64 = row.iter().sum();
                    row.iter().map(|v| v / t).collect()
                })
                .collect()
        })
        .collect();
    (cost, p)
}

fn policies(n: usize, na: usize) -> impl Iterator<Item = Vec<usize>> {
    (0..na.pow(n as u32)).map(move |mut k| {
        (0..n)
            .map(|_| {
                let a = k % na;
                k /= na;
                a
            })
            .collect()
    })
}

/// J_μ = (I − γP_μ)⁻¹ g_μ, solved here independently of the crate.
fn exact_value(cost: &[Vec<f64>], p: &[Vec<Vec<f64>>], pol: &[usize], gamma: f64) -> Vec<f64> {
    let n = cost.len();
    let a = DMatrix::from_fn(n, n, |i, j| {
        f64::from(u8::from(i == j)) - gamma * p[pol[i]][i][j]
    });
    let g = DVector::from_fn(n, |i, _| cost[i][pol[i]]);
    a.lu().solve(&g).unwrap().iter().copied().collect()
}

/// π_μ g_μ with π by power iteration of the lazy chain (independent of the
/// crate's LU solve).
fn stationary_cost(cost: &[Vec<f64>], p: &[Vec<Vec<f64>>], pol: &[usize]) -> f64 {
    let n = cost.len();
    let mut pi = vec![1.0 / n as f64; n];
    for _ in 0..20_000 {
        let mut next = vec![0.0; n];
        for i in 0..n {
            for j in 0..n {
                next[j] += pi[i] * 0.5 * (p[pol[i]][i][j] + f64::from(u8::from(i == j)));
            }
        }
        pi = next;
    }
    (0..n).map(|i| pi[i] * cost[i][pol[i]]).sum()
}

#[test]
fn value_iteration_equals_the_best_policy_by_enumeration_and_policy_iteration() {
    for seed in 0..6 {
        let (n, na, gamma) = (4, 3, 0.9);
        let (cost, p) = random_mdp(n, na, seed, seed % 2 == 1);
        let mdp = FiniteMdp::from_dense(&cost, &p).unwrap();
        let eps = 1e-8;
        let vi = mdp.value_iteration(gamma, eps, 100_000).unwrap();
        let mut best = vec![f64::INFINITY; n];
        for pol in policies(n, na) {
            let v = exact_value(&cost, &p, &pol, gamma);
            for i in 0..n {
                best[i] = best[i].min(v[i]);
            }
        }
        // The optimal value is attained by one policy in every state; VI's
        // values and its greedy policy's exact value are both within eps.
        let v_pol = exact_value(&cost, &p, &vi.policy, gamma);
        for i in 0..n {
            assert!(
                (vi.values[i] - best[i]).abs() < eps,
                "seed {seed} state {i}: VI {} vs exact {}",
                vi.values[i],
                best[i]
            );
            assert!(
                v_pol[i] - best[i] < eps,
                "seed {seed}: VI policy is not optimal in state {i}"
            );
        }
        let pi = mdp.policy_iteration(gamma, 100).unwrap();
        for i in 0..n {
            assert!(
                (pi.values[i] - best[i]).abs() < 1e-9,
                "seed {seed}: PI {} vs {}",
                pi.values[i],
                best[i]
            );
        }
        let lib = mdp.evaluate_discounted(&vi.policy, gamma).unwrap();
        for i in 0..n {
            assert!((lib[i] - v_pol[i]).abs() < 1e-9);
        }
    }
}

#[test]
fn relative_value_iteration_gain_equals_the_best_stationary_average_cost() {
    for seed in 10..16 {
        let (n, na) = (4, 3);
        let (cost, p) = random_mdp(n, na, seed, false);
        let mdp = FiniteMdp::from_dense(&cost, &p).unwrap();
        let rvi = mdp.relative_value_iteration(0.5, 1e-10, 1_000_000).unwrap();
        let best = policies(n, na)
            .map(|pol| stationary_cost(&cost, &p, &pol))
            .fold(f64::INFINITY, f64::min);
        assert!(
            (rvi.gain - best).abs() < 1e-8,
            "seed {seed}: gain {} vs best {best}",
            rvi.gain
        );
        assert!(rvi.gain_bounds.0 <= best + 1e-9 && best <= rvi.gain_bounds.1 + 1e-9);
        let own = stationary_cost(&cost, &p, &rvi.policy);
        assert!(
            (own - best).abs() < 1e-8,
            "seed {seed}: RVI policy averages {own}, best {best}"
        );
        let lib = mdp.stationary_average_cost(&rvi.policy).unwrap();
        assert!((lib - own).abs() < 1e-9);
    }
}

#[test]
fn relative_value_iteration_converges_on_a_periodic_chain() {
    // Two states swapping deterministically (period 2): plain RVI would
    // oscillate; the aperiodic transform converges to the gain (3 + 7)/2,
    // against the alternative of staying put at cost 6 in state 0.
    let cost = vec![vec![3.0, 6.0], vec![7.0, 7.0]];
    let swap = vec![vec![0.0, 1.0], vec![1.0, 0.0]];
    let stay = vec![vec![1.0, 0.0], vec![1.0, 0.0]];
    let mdp = FiniteMdp::from_dense(&cost, &[swap, stay]).unwrap();
    let rvi = mdp.relative_value_iteration(0.5, 1e-12, 100_000).unwrap();
    assert!((rvi.gain - 5.0).abs() < 1e-9, "gain {}", rvi.gain);
    assert_eq!(rvi.policy[0], 0);
}

#[test]
fn bad_rows_and_parameters_are_refused() {
    let mut m = FiniteMdp::with_capacity(2, 1, 4);
    assert!(m.push_row(1.0, &[(0, 0.5), (1, 0.4)]).is_err());
    assert!(m.push_row(1.0, &[(2, 1.0)]).is_err());
    assert!(m.push_row(f64::NAN, &[(0, 1.0)]).is_err());
    let (cost, p) = random_mdp(3, 2, 1, false);
    let mdp = FiniteMdp::from_dense(&cost, &p).unwrap();
    assert!(mdp.value_iteration(1.0, 1e-6, 10).is_err());
    assert!(mdp.value_iteration(0.9, 1e-12, 2).is_err());
    assert!(mdp.relative_value_iteration(0.0, 1e-6, 10).is_err());
}
