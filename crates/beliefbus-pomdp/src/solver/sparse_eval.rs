//! Test support: a finite-state controller's value by Gauss–Seidel
//! sweeps over its sparse product chain, with a rigorous error bound.
//!
//! The controller (node k acts a_k, moves to σ_k(o) on o) and the POMDP
//! make a Markov reward process on pairs (k, s):
//!
//! ```text
//! V(k,s) = R(s,a_k) + γ Σ_{s'} T(s'|s,a_k) Σ_o O(o|s',a_k) V(σ_k(o), s')
//! ```
//!
//! written here as `V = r + γ P V` with P built explicitly (entries that
//! land on the same (k', s') merged). The sweeps may start anywhere; what
//! makes the answer trustworthy is the a-posteriori bound of the last,
//! Jacobi, application: with `r = ‖HV − V‖∞` the fixed point V* obeys
//! `‖V* − HV‖∞ ≤ γ r/(1−γ)` (H is a γ-contraction:
//! `‖V* − HV‖ ≤ γ‖V* − V‖ ≤ γ(‖V* − HV‖ + r)`). Neither the sweeps nor
//! the bound share code with [`super::graph::evaluate`] (which sweeps the
//! controller node by node without building P and certifies a one-sided
//! shift); [`super::dense_eval`] checks this on small controllers.

use super::graph::Controller;
use crate::model::Pomdp;

/// The product chain `V = r + γ P V` in compressed rows.
struct ProductChain {
    reward: Vec<f64>,
    offsets: Vec<usize>,
    cols: Vec<u32>,
    /// γ · P entries.
    vals: Vec<f64>,
}

impl ProductChain {
    fn new(p: &Pomdp, c: &Controller) -> Self {
        let (ns, no) = (p.n_states(), p.n_obs());
        let n = c.len() * ns;
        let mut reward = Vec::with_capacity(n);
        let mut offsets = vec![0];
        let mut cols = Vec::new();
        let mut vals = Vec::new();
        let mut row: Vec<(u32, f64)> = Vec::new();
        for (k, &a) in c.action.iter().enumerate() {
            let next = &c.next[k * no..(k + 1) * no];
            for s in 0..ns {
                reward.push(p.reward[a][s]);
                row.clear();
                let (s2s, ts) = p.trans[a].row(s);
                for (&s2, &t) in s2s.iter().zip(ts) {
                    let (os, qs) = p.obs[a].row(s2 as usize);
                    for (&o, &q) in os.iter().zip(qs) {
                        let col = next[o as usize] as usize * ns + s2 as usize;
                        row.push((col as u32, p.discount * t * q));
                    }
                }
                row.sort_by_key(|e| e.0);
                let start = cols.len();
                for &(j, w) in &row {
                    if cols.len() > start && cols.last() == Some(&j) {
                        *vals.last_mut().expect("pushed with cols") += w;
                    } else {
                        cols.push(j);
                        vals.push(w);
                    }
                }
                offsets.push(cols.len());
            }
        }
        ProductChain {
            reward,
            offsets,
            cols,
            vals,
        }
    }

    /// `r_i + Σ_j γ P_ij v_j`.
    fn apply_row(&self, i: usize, v: &[f64]) -> f64 {
        let (a, b) = (self.offsets[i], self.offsets[i + 1]);
        self.reward[i]
            + self.cols[a..b]
                .iter()
                .zip(&self.vals[a..b])
                .map(|(&j, &w)| w * v[j as usize])
                .sum::<f64>()
    }
}

/// The controller's value per node and a bound `e` with
/// `|V_true(k,s) − value[k][s]| ≤ e` (module doc), from Gauss–Seidel
/// sweeps started at `start` (any vectors; e.g. the certified values
/// under test, which only speeds the sweeps up) until a sweep changes no
/// entry by more than `tol`, at most `max_sweeps`.
pub(crate) fn iterative_value(
    p: &Pomdp,
    c: &Controller,
    start: Option<&[Vec<f64>]>,
    tol: f64,
    max_sweeps: usize,
) -> (Vec<Vec<f64>>, f64) {
    let ns = p.n_states();
    let chain = ProductChain::new(p, c);
    let n = chain.reward.len();
    let mut v: Vec<f64> = match start {
        Some(s) => s.iter().flatten().copied().collect(),
        None => vec![0.0; n],
    };
    assert_eq!(v.len(), n, "one start vector of |S| per node");
    for _ in 0..max_sweeps {
        let mut change = 0.0f64;
        for i in 0..n {
            let x = chain.apply_row(i, &v);
            change = change.max((x - v[i]).abs());
            v[i] = x;
        }
        if change < tol {
            break;
        }
    }
    let hv: Vec<f64> = (0..n).map(|i| chain.apply_row(i, &v)).collect();
    let r = hv
        .iter()
        .zip(&v)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f64, f64::max);
    let g = p.discount;
    let bound = g * r / (1.0 - g);
    (hv.chunks(ns).map(<[f64]>::to_vec).collect(), bound)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::dense_eval::exact_value;
    use crate::solver::{graph, solve, SolveOptions};
    use std::time::Duration;

    fn controllers(p: &Pomdp) -> Vec<Controller> {
        let sol = solve(
            p,
            &SolveOptions {
                precision: 1e-3,
                time_limit: Some(Duration::from_secs(5)),
                threads: 1,
                prune_lower: false,
                ..Default::default()
            },
            |_| {},
        )
        .expect("solves");
        sol.plan_nodes
            .iter()
            .map(|&n| {
                let (_, action, next) = graph::reachable(&sol.plan, n);
                Controller {
                    values: Vec::new(),
                    action,
                    next,
                }
            })
            .collect()
    }

    fn problem(name: &str, text: &str) -> Pomdp {
        crate::parse_str(name, text).expect("parses")
    }

    /// On every plan of two small solved problems, the sweeps' value and
    /// the dense LU solve agree to 1e-9, and the bound covers the
    /// difference.
    #[test]
    fn iterative_value_agrees_with_the_dense_solve() {
        let probs = [
            problem(
                "two_state_mdp.pomdp",
                include_str!("../../tests/data/two_state_mdp.pomdp"),
            ),
            problem(
                "noisy_two_state.pomdp",
                include_str!("../../tests/data/noisy_two_state.pomdp"),
            ),
        ];
        let mut checked = 0;
        for p in &probs {
            for c in controllers(p) {
                let exact = exact_value(p, &c);
                let (v, e) = iterative_value(p, &c, None, 1e-13, 1_000_000);
                assert!(e < 1e-10, "bound {e}");
                for (x, y) in v.iter().flatten().zip(exact.iter().flatten()) {
                    assert!((x - y).abs() <= e + 1e-9, "{x} vs dense {y} (bound {e})");
                }
                checked += 1;
            }
        }
        assert!(checked >= 4, "{checked} controllers");
    }

    /// A loose tolerance gives a loose answer, and the bound says so: it
    /// still covers the true error (never claims more than it has).
    #[test]
    fn the_bound_covers_a_stopped_iteration() {
        let p = problem(
            "noisy_two_state.pomdp",
            include_str!("../../tests/data/noisy_two_state.pomdp"),
        );
        let c = controllers(&p).pop().expect("a plan");
        let exact = exact_value(&p, &c);
        for sweeps in [1, 3, 10, 30] {
            let (v, e) = iterative_value(&p, &c, None, 0.0, sweeps);
            let err = v
                .iter()
                .flatten()
                .zip(exact.iter().flatten())
                .map(|(x, y)| (x - y).abs())
                .fold(0.0f64, f64::max);
            assert!(
                err <= e + 1e-9,
                "{sweeps} sweeps: error {err} above bound {e}"
            );
            assert!(err > 1e-6 || sweeps > 3, "{sweeps} sweeps already exact");
        }
    }
}
