//! The lower bound: a set Γ of α-vectors, `V̲(b) = max_{α∈Γ} α·b`.
//!
//! Every α is the value of a conditional plan, so any subset of Γ is still a
//! lower bound; this is what makes pruning safe.
//!
//! * Initialisation (blind policies, Hauskrecht 2000): for each action, the
//!   value of repeating it forever, `α_a = R_a + γ T_a α_a`, iterated from
//!   `min R / (1−γ)` — every iterate is below the fixed point, so stopping
//!   early stays a lower bound.
//! * Point-based backup at b (Pineau et al. 2003, eq. 7): for each action
//!   take, per observation, the α best at `b^{a,o}`; then
//!   `α(s) = R(s,a) + γ Σ_{s'} T(s'|s,a) Σ_o O(o|s',a) α_{a,o}(s')` for the
//!   action whose value at b is largest.
//! * Pruning: a new α removes those it dominates pointwise, and
//!   [`LowerBound::prune`] keeps only vectors best at some sampled belief
//!   (SARSOP's pruning by sampled beliefs).

use super::graph::PlanGraph;
use crate::belief::{Branch, SparseBelief};
use crate::model::Pomdp;

pub struct LowerBound {
    pub vectors: Vec<Vec<f64>>,
    pub actions: Vec<usize>,
    /// The plan node of each vector in [`LowerBound::graph`].
    pub nodes: Vec<u32>,
    /// Every kept vector's plan ([`super::graph`]).
    pub graph: PlanGraph,
}

impl LowerBound {
    /// Blind-policy vectors, iterated until the change is below `tol`.
    pub fn blind(p: &Pomdp, tol: f64, max_iter: usize) -> Self {
        let (lo, _) = p.reward_range();
        let g = p.discount;
        let n = p.n_states();
        let mut lb = LowerBound {
            vectors: Vec::new(),
            actions: Vec::new(),
            nodes: Vec::new(),
            graph: PlanGraph::new(p.n_obs()),
        };
        for a in 0..p.n_actions() {
            let mut v = vec![lo / (1.0 - g); n];
            let mut next = vec![0.0; n];
            for _ in 0..max_iter {
                let mut change: f64 = 0.0;
                for s in 0..n {
                    let (cols, vals) = p.trans[a].row(s);
                    let ev: f64 = cols
                        .iter()
                        .zip(vals)
                        .map(|(&j, &t)| t * v[j as usize])
                        .sum();
                    next[s] = p.reward[a][s] + g * ev;
                    change = change.max((next[s] - v[s]).abs());
                }
                std::mem::swap(&mut v, &mut next);
                if change < tol {
                    break;
                }
            }
            let node = lb.graph.push_loop(a);
            lb.add(v, a, node);
        }
        lb
    }

    /// Index and value of the best vector at `b`.
    pub fn best(&self, b: &SparseBelief) -> (usize, f64) {
        let mut best = (0, f64::NEG_INFINITY);
        for (k, v) in self.vectors.iter().enumerate() {
            let x = b.dot(v);
            if x > best.1 {
                best = (k, x);
            }
        }
        best
    }

    pub fn value(&self, b: &SparseBelief) -> f64 {
        self.best(b).1
    }

    /// `max_a [R(b,a) + γ Σ_o P(o|b,a) V̲(b^{a,o})]` at `b` and the α that
    /// attains it (with its action and the plan node it continues with on
    /// each observation). `branches[a]` are b's successors.
    pub fn backup(
        &self,
        p: &Pomdp,
        b: &SparseBelief,
        branches: &[Vec<Branch>],
    ) -> (Vec<f64>, usize, f64, Vec<u32>) {
        let g = p.discount;
        let fallback = self.best(b).0;
        let mut best_a = (0, f64::NEG_INFINITY);
        let mut chosen = vec![fallback; p.n_obs()];
        let mut best_chosen = chosen.clone();
        for (a, br) in branches.iter().enumerate() {
            chosen.iter_mut().for_each(|c| *c = fallback);
            let mut q = b.dot(&p.reward[a]);
            for branch in br {
                let (k, v) = self.best(&branch.belief);
                chosen[branch.obs as usize] = k;
                q += g * branch.prob * v;
            }
            if q > best_a.1 {
                best_a = (a, q);
                best_chosen.copy_from_slice(&chosen);
            }
        }
        let a = best_a.0;
        let n = p.n_states();
        // w(s') = Σ_o O(o|s',a) α_{a,o}(s')
        let mut w = vec![0.0; n];
        for s2 in 0..n {
            let (obs, probs) = p.obs[a].row(s2);
            w[s2] = obs
                .iter()
                .zip(probs)
                .map(|(&o, &po)| po * self.vectors[best_chosen[o as usize]][s2])
                .sum();
        }
        let alpha: Vec<f64> = (0..n)
            .map(|s| {
                let (cols, vals) = p.trans[a].row(s);
                let ev: f64 = cols
                    .iter()
                    .zip(vals)
                    .map(|(&j, &t)| t * w[j as usize])
                    .sum();
                p.reward[a][s] + g * ev
            })
            .collect();
        let next = best_chosen.iter().map(|&k| self.nodes[k]).collect();
        (alpha, a, best_a.1, next)
    }

    /// The vector dominating `alpha` pointwise, if any.
    fn dominating(&self, alpha: &[f64]) -> Option<usize> {
        self.vectors
            .iter()
            .position(|v| v.iter().zip(alpha).all(|(x, y)| x >= y))
    }

    /// Adds the backed-up `alpha` (plan: `action`, then `next[o]`) unless
    /// an existing vector dominates it pointwise; see [`LowerBound::add`].
    pub fn add_plan(&mut self, alpha: Vec<f64>, action: usize, next: &[u32]) -> bool {
        if self.dominating(&alpha).is_some() {
            return false;
        }
        let node = self.graph.push(action, next);
        self.add(alpha, action, node)
    }

    /// Adds `alpha`, the value of plan node `node`, unless an existing
    /// vector dominates it pointwise (the node is then redirected to that
    /// vector's); removes the vectors it dominates (redirecting their
    /// nodes to `node`). Returns whether it was added.
    pub fn add(&mut self, alpha: Vec<f64>, action: usize, node: u32) -> bool {
        if let Some(k) = self.dominating(&alpha) {
            self.graph.replace(node, self.nodes[k]);
            return false;
        }
        let mut k = 0;
        while k < self.vectors.len() {
            if alpha.iter().zip(&self.vectors[k]).all(|(x, y)| x >= y) {
                self.vectors.swap_remove(k);
                self.actions.swap_remove(k);
                let old = self.nodes.swap_remove(k);
                self.graph.replace(old, node);
            } else {
                k += 1;
            }
        }
        self.vectors.push(alpha);
        self.actions.push(action);
        self.nodes.push(node);
        true
    }

    /// Keeps only the vectors that are best at one of `beliefs`.
    pub fn prune<'a>(&mut self, beliefs: impl Iterator<Item = &'a SparseBelief>) {
        let mut keep = vec![false; self.vectors.len()];
        for b in beliefs {
            keep[self.best(b).0] = true;
        }
        let mut k = 0;
        self.vectors.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        let mut k = 0;
        self.actions.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        let mut k = 0;
        self.nodes.retain(|_| {
            k += 1;
            keep[k - 1]
        });
    }
}
