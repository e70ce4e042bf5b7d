//! A finite MDP with sparse transitions and its solvers: value iteration
//! (discounted), relative value iteration (average cost), and — for small
//! problems and as exact references — policy iteration and the linear
//! solves of a fixed policy's Bellman equation and stationary distribution.
//!
//! Discounted Bellman operator (the paper's eq. 10 on the grid):
//! (TJ)(i) = min_a [ g(i,a) + γ Σ_j P(j | i,a) J(j) ].
//!
//! Average cost: the relative value iteration of White on the aperiodic
//! transform P_τ = τ I + (1 − τ) P, which has the same stationary
//! distributions (π P_τ = π) and therefore the same gain and optimal
//! policies, but every chain aperiodic so the iteration converges.

use crate::ProjectionError;
use nalgebra::{DMatrix, DVector};

/// A finite MDP: costs g(s,a) and sparse rows P(· | s,a).
#[derive(Clone, Debug)]
pub struct FiniteMdp {
    n_states: usize,
    n_actions: usize,
    cost: Vec<f64>,
    row_start: Vec<usize>,
    next: Vec<u32>,
    prob: Vec<f64>,
}

/// The solution of a discounted problem.
#[derive(Clone, Debug)]
pub struct DiscountedSolution {
    pub values: Vec<f64>,
    pub policy: Vec<usize>,
    pub iterations: usize,
    /// ‖J_n − J_{n−1}‖_∞ at the stop.
    pub residual: f64,
}

/// The solution of an average-cost problem.
#[derive(Clone, Debug)]
pub struct AverageSolution {
    /// The gain estimate (midpoint of `gain_bounds`).
    pub gain: f64,
    /// min_i and max_i of (T h − h)(i) at the stop: the optimal gain lies in
    /// between (Odoni's bounds).
    pub gain_bounds: (f64, f64),
    /// Relative values h (h(reference) = 0), of the aperiodic transform.
    pub bias: Vec<f64>,
    pub policy: Vec<usize>,
    pub iterations: usize,
}

impl FiniteMdp {
    /// An empty MDP to fill row by row with [`FiniteMdp::push_row`] in the
    /// order (s = 0, a = 0), (0, 1), …, (1, 0), ….
    pub fn with_capacity(n_states: usize, n_actions: usize, nnz: usize) -> Self {
        let mut row_start = Vec::with_capacity(n_states * n_actions + 1);
        row_start.push(0);
        Self {
            n_states,
            n_actions,
            cost: Vec::with_capacity(n_states * n_actions),
            row_start,
            next: Vec::with_capacity(nnz),
            prob: Vec::with_capacity(nnz),
        }
    }

    /// Append the row of the next (state, action): cost and (next, prob)
    /// pairs; probabilities must be non-negative and sum to one.
    pub fn push_row(&mut self, cost: f64, entries: &[(u32, f64)]) -> Result<(), ProjectionError> {
        let total: f64 = entries.iter().map(|e| e.1).sum();
        if !cost.is_finite()
            || (total - 1.0).abs() > 1e-9
            || entries
                .iter()
                .any(|&(j, p)| !(p >= 0.0) || j as usize >= self.n_states)
        {
            return Err(ProjectionError::invalid(
                "MDP row",
                format!(
                    "row {} has cost {cost} and probabilities summing to {total}",
                    self.cost.len()
                ),
            ));
        }
        if self.cost.len() >= self.n_states * self.n_actions {
            return Err(ProjectionError::invalid(
                "MDP row",
                "more rows than states × actions",
            ));
        }
        self.cost.push(cost);
        for &(j, p) in entries {
            self.next.push(j);
            self.prob.push(p);
        }
        self.row_start.push(self.next.len());
        Ok(())
    }

    /// Concatenate row blocks built in parallel (each a complete run of
    /// states, in order).
    pub fn concat(
        n_states: usize,
        n_actions: usize,
        parts: Vec<FiniteMdp>,
    ) -> Result<Self, ProjectionError> {
        let nnz = parts.iter().map(|p| p.next.len()).sum();
        let mut out = Self::with_capacity(n_states, n_actions, nnz);
        for p in parts {
            for r in 0..p.cost.len() {
                let (a, b) = (p.row_start[r], p.row_start[r + 1]);
                out.cost.push(p.cost[r]);
                out.next.extend_from_slice(&p.next[a..b]);
                out.prob.extend_from_slice(&p.prob[a..b]);
                out.row_start.push(out.next.len());
            }
        }
        out.check_complete()?;
        Ok(out)
    }

    /// A dense MDP: `cost[s][a]`, `p[a][s][s']`.
    pub fn from_dense(cost: &[Vec<f64>], p: &[Vec<Vec<f64>>]) -> Result<Self, ProjectionError> {
        let n = cost.len();
        let na = p.len();
        let mut m = Self::with_capacity(n, na, n * n * na);
        let mut row = Vec::new();
        for s in 0..n {
            ProjectionError::check_len("cost row", na, cost[s].len())?;
            for a in 0..na {
                ProjectionError::check_len("transition row", n, p[a][s].len())?;
                row.clear();
                row.extend(
                    p[a][s]
                        .iter()
                        .enumerate()
                        .filter(|e| *e.1 > 0.0)
                        .map(|(j, &q)| (j as u32, q)),
                );
                m.push_row(cost[s][a], &row)?;
            }
        }
        m.check_complete()?;
        Ok(m)
    }

    fn check_complete(&self) -> Result<(), ProjectionError> {
        ProjectionError::check_len("MDP rows", self.n_states * self.n_actions, self.cost.len())
    }

    pub fn n_states(&self) -> usize {
        self.n_states
    }

    pub fn n_actions(&self) -> usize {
        self.n_actions
    }

    /// The number of stored transition entries.
    pub fn nnz(&self) -> usize {
        self.next.len()
    }

    /// g(s, a).
    pub fn cost(&self, s: usize, a: usize) -> f64 {
        self.cost[s * self.n_actions + a]
    }

    /// Σ_j P(j | s,a) v(j).
    pub fn expect(&self, s: usize, a: usize, v: &[f64]) -> f64 {
        let r = s * self.n_actions + a;
        let (lo, hi) = (self.row_start[r], self.row_start[r + 1]);
        self.next[lo..hi]
            .iter()
            .zip(&self.prob[lo..hi])
            .map(|(&j, &p)| p * v[j as usize])
            .sum()
    }

    /// The (value, argmin action) of g(s,a) + β Σ P v + τ v(s) over a;
    /// ties go to the lowest action index.
    fn backup(&self, s: usize, v: &[f64], beta: f64, tau: f64) -> (f64, usize) {
        let mut best = (f64::INFINITY, 0);
        for a in 0..self.n_actions {
            let q = self.cost(s, a) + beta * self.expect(s, a, v) + tau * v[s];
            if q < best.0 {
                best = (q, a);
            }
        }
        best
    }

    fn check_policy(&self, policy: &[usize]) -> Result<(), ProjectionError> {
        ProjectionError::check_len("policy", self.n_states, policy.len())?;
        if policy.iter().any(|&a| a >= self.n_actions) {
            return Err(ProjectionError::invalid("policy", "action out of range"));
        }
        Ok(())
    }

    /// Value iteration from J = 0. Stops when ‖J_{n+1} − J_n‖_∞ <
    /// ε(1 − γ)/(2γ), which makes the greedy policy's value ε-optimal
    /// (Puterman, Thm. 6.3.1); errors if `max_iter` sweeps do not reach it.
    pub fn value_iteration(
        &self,
        gamma: f64,
        eps: f64,
        max_iter: usize,
    ) -> Result<DiscountedSolution, ProjectionError> {
        if !(gamma > 0.0 && gamma < 1.0 && eps > 0.0) {
            return Err(ProjectionError::invalid(
                "value iteration",
                format!("gamma {gamma} must be in (0,1), eps {eps} > 0"),
            ));
        }
        let threshold = eps * (1.0 - gamma) / (2.0 * gamma);
        let n = self.n_states;
        let mut v = vec![0.0; n];
        let mut w = vec![0.0; n];
        let mut policy = vec![0; n];
        for it in 1..=max_iter {
            let mut res: f64 = 0.0;
            for s in 0..n {
                let (q, a) = self.backup(s, &v, gamma, 0.0);
                res = res.max((q - v[s]).abs());
                w[s] = q;
                policy[s] = a;
            }
            std::mem::swap(&mut v, &mut w);
            if res < threshold {
                // The greedy policy with respect to the final values.
                for s in 0..n {
                    policy[s] = self.backup(s, &v, gamma, 0.0).1;
                }
                return Ok(DiscountedSolution {
                    values: v,
                    policy,
                    iterations: it,
                    residual: res,
                });
            }
        }
        Err(ProjectionError::invalid(
            "value iteration",
            format!("no convergence in {max_iter} sweeps"),
        ))
    }

    /// Relative value iteration on P_τ = τI + (1 − τ)P, h(ref = 0) pinned to
    /// zero. Stops when span(T h − h) < ε: the optimal gain is then within
    /// [min, max] of T h − h, an interval of width < ε.
    pub fn relative_value_iteration(
        &self,
        tau: f64,
        eps: f64,
        max_iter: usize,
    ) -> Result<AverageSolution, ProjectionError> {
        if !(tau > 0.0 && tau < 1.0 && eps > 0.0) {
            return Err(ProjectionError::invalid(
                "relative value iteration",
                format!("tau {tau} must be in (0,1), eps {eps} > 0"),
            ));
        }
        let n = self.n_states;
        let mut h = vec![0.0; n];
        let mut th = vec![0.0; n];
        let mut policy = vec![0; n];
        for it in 1..=max_iter {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for s in 0..n {
                let (q, a) = self.backup(s, &h, 1.0 - tau, tau);
                th[s] = q;
                policy[s] = a;
                lo = lo.min(q - h[s]);
                hi = hi.max(q - h[s]);
            }
            let shift = th[0];
            for s in 0..n {
                h[s] = th[s] - shift;
            }
            if hi - lo < eps {
                return Ok(AverageSolution {
                    gain: 0.5 * (lo + hi),
                    gain_bounds: (lo, hi),
                    bias: h,
                    policy,
                    iterations: it,
                });
            }
        }
        Err(ProjectionError::invalid(
            "relative value iteration",
            format!("no convergence in {max_iter} sweeps (multichain MDP?)"),
        ))
    }

    /// The dense transition matrix and cost vector of a fixed policy.
    fn policy_chain(&self, policy: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.n_states;
        let mut p = DMatrix::zeros(n, n);
        let mut c = DVector::zeros(n);
        for s in 0..n {
            let r = s * self.n_actions + policy[s];
            c[s] = self.cost[r];
            for k in self.row_start[r]..self.row_start[r + 1] {
                p[(s, self.next[k] as usize)] += self.prob[k];
            }
        }
        (p, c)
    }

    /// J_μ = (I − γ P_μ)⁻¹ g_μ by a dense LU solve (small MDPs).
    pub fn evaluate_discounted(
        &self,
        policy: &[usize],
        gamma: f64,
    ) -> Result<Vec<f64>, ProjectionError> {
        self.check_policy(policy)?;
        let (p, c) = self.policy_chain(policy);
        let a = DMatrix::identity(self.n_states, self.n_states) - p * gamma;
        a.lu()
            .solve(&c)
            .map(|v| v.iter().copied().collect())
            .ok_or_else(|| ProjectionError::invalid("policy evaluation", "singular system"))
    }

    /// The stationary average cost π_μ g_μ of a unichain policy: π solves
    /// π(I − P_μ) = 0 with Σπ = 1 (one balance equation replaced by the
    /// normalisation), dense LU (small MDPs).
    pub fn stationary_average_cost(&self, policy: &[usize]) -> Result<f64, ProjectionError> {
        self.check_policy(policy)?;
        let n = self.n_states;
        let (p, c) = self.policy_chain(policy);
        let mut a = (DMatrix::identity(n, n) - p).transpose();
        let mut rhs = DVector::zeros(n);
        for j in 0..n {
            a[(n - 1, j)] = 1.0;
        }
        rhs[n - 1] = 1.0;
        let pi = a.lu().solve(&rhs).ok_or_else(|| {
            ProjectionError::invalid("stationary distribution", "singular (not unichain)")
        })?;
        Ok(pi.dot(&c))
    }

    /// Howard's policy iteration with exact evaluation (small MDPs):
    /// improve only where strictly better, so it terminates.
    pub fn policy_iteration(
        &self,
        gamma: f64,
        max_iter: usize,
    ) -> Result<DiscountedSolution, ProjectionError> {
        let n = self.n_states;
        let mut policy = vec![0; n];
        for it in 1..=max_iter {
            let v = self.evaluate_discounted(&policy, gamma)?;
            let mut changed = false;
            for s in 0..n {
                let (q, a) = self.backup(s, &v, gamma, 0.0);
                let current = self.cost(s, policy[s]) + gamma * self.expect(s, policy[s], &v);
                if q < current - 1e-12 * (1.0 + current.abs()) {
                    policy[s] = a;
                    changed = true;
                }
            }
            if !changed {
                return Ok(DiscountedSolution {
                    values: v,
                    policy,
                    iterations: it,
                    residual: 0.0,
                });
            }
        }
        Err(ProjectionError::invalid(
            "policy iteration",
            format!("no convergence in {max_iter} iterations"),
        ))
    }
}
