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
    /// Change only through [`LowerBound::add`] and [`LowerBound::prune`]:
    /// they keep [`LowerBound::by_state`] in step.
    pub vectors: Vec<Vec<f64>>,
    pub actions: Vec<usize>,
    /// The plan node of each vector in [`LowerBound::graph`].
    pub nodes: Vec<u32>,
    /// Every kept vector's plan ([`super::graph`]).
    pub graph: PlanGraph,
    /// The vectors transposed, `by_state[s·cap + k] = vectors[k][s]`:
    /// [`LowerBound::best`] at a sparse belief then reads one contiguous
    /// run of |Γ| values per state of its support instead of gathering
    /// from every vector, the backups' dominant cost when Γ holds
    /// thousands of vectors.
    by_state: Vec<f64>,
    cap: usize,
}

/// Vectors scored together by [`LowerBound::best`] (a stack buffer).
const BEST_CHUNK: usize = 64;

/// The value of repeating each action for ever, `α_a = R_a + γ T_a α_a`,
/// iterated from `min R/(1−γ)` until the change is below `tol`: every
/// iterate is below the fixed point, so each is a lower bound.
pub fn blind_vectors(p: &Pomdp, tol: f64, max_iter: usize) -> Vec<Vec<f64>> {
    let (lo, _) = p.reward_range();
    let g = p.discount;
    let n = p.n_states();
    (0..p.n_actions())
        .map(|a| {
            let mut v = vec![lo / (1.0 - g); n];
            let mut next = vec![0.0; n];
            for _ in 0..max_iter {
                let mut change: f64 = 0.0;
                for s in 0..n {
                    next[s] = p.backup_at(a, s, &v);
                    change = change.max((next[s] - v[s]).abs());
                }
                std::mem::swap(&mut v, &mut next);
                if change < tol {
                    break;
                }
            }
            v
        })
        .collect()
}

impl LowerBound {
    /// Blind-policy vectors, iterated until the change is below `tol`.
    pub fn blind(p: &Pomdp, tol: f64, max_iter: usize) -> Self {
        Self::from_blind(p, &blind_vectors(p, tol, max_iter))
    }

    /// Γ holding `blind[a]` as the value of repeating action a.
    pub fn from_blind(p: &Pomdp, blind: &[Vec<f64>]) -> Self {
        let mut lb = LowerBound {
            vectors: Vec::new(),
            actions: Vec::new(),
            nodes: Vec::new(),
            graph: PlanGraph::new(p.n_obs()),
            by_state: Vec::new(),
            cap: 0,
        };
        for (a, v) in blind.iter().enumerate() {
            let node = lb.graph.push_loop(a);
            lb.add(v.clone(), a, node);
        }
        lb
    }

    /// Index and value of the best vector at `b`.
    /// Ties go to the lowest index; each `α·b` is summed in the support's
    /// order, as [`SparseBelief::dot`] does, so the result is the same to
    /// the bit as scoring the vectors one by one.
    pub fn best(&self, b: &SparseBelief) -> (usize, f64) {
        let mut best = (0, f64::NEG_INFINITY);
        let n = self.vectors.len();
        let mut acc = [0.0f64; BEST_CHUNK];
        let mut start = 0;
        while start < n {
            let len = BEST_CHUNK.min(n - start);
            let acc = &mut acc[..len];
            // −0.0 is the identity of f64 addition, as in `Iterator::sum`.
            acc.iter_mut().for_each(|x| *x = -0.0);
            for (&s, &p) in b.idx.iter().zip(&b.val) {
                let row = s as usize * self.cap + start;
                for (x, &v) in acc.iter_mut().zip(&self.by_state[row..row + len]) {
                    *x += p * v;
                }
            }
            for (j, &x) in acc.iter().enumerate() {
                if x > best.1 {
                    best = (start + j, x);
                }
            }
            start += len;
        }
        best
    }

    /// Rebuilds [`LowerBound::by_state`] with room for `cap` vectors.
    fn rebuild(&mut self, cap: usize) {
        let ns = self.vectors.first().map_or(0, Vec::len);
        self.cap = cap;
        self.by_state.clear();
        self.by_state.resize(ns * cap, 0.0);
        for (k, v) in self.vectors.iter().enumerate() {
            for (s, &x) in v.iter().enumerate() {
                self.by_state[s * cap + k] = x;
            }
        }
    }

    /// Removes vector `k` (the last takes its place, as `swap_remove`).
    fn remove(&mut self, k: usize) -> u32 {
        let last = self.vectors.len() - 1;
        if k != last {
            for s in 0..self.vectors[k].len() {
                self.by_state[s * self.cap + k] = self.by_state[s * self.cap + last];
            }
        }
        self.vectors.swap_remove(k);
        self.actions.swap_remove(k);
        self.nodes.swap_remove(k)
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
        self.add_protecting(alpha, action, node, &std::collections::HashSet::new())
    }

    /// [`LowerBound::add`], except that protected nodes (those in
    /// `protect` after redirects) are never redirected: the dominated
    /// vectors whose nodes are protected leave Γ with their plans intact,
    /// and if `alpha` itself is dominated, `node` keeps its plan when it is
    /// protected. A controller certified as it stands keeps its plans.
    ///
    /// Redirecting a node is sound only if every vector standing for it is
    /// below the vector it is sent to. A node that already holds a vector
    /// in Γ (the plan behind V̲(b₀), given its evaluated value as a second
    /// vector) fails that when its evaluation, cut short, came out low
    /// enough to be dominated: the first vector would then stand for a
    /// plan worth less than it claims.
    pub fn add_protecting(
        &mut self,
        alpha: Vec<f64>,
        action: usize,
        node: u32,
        protect: &std::collections::HashSet<u32>,
    ) -> bool {
        if let Some(k) = self.dominating(&alpha) {
            if !protect.contains(&self.graph.resolve(node)) {
                self.graph.replace(node, self.nodes[k]);
            }
            return false;
        }
        let mut k = 0;
        while k < self.vectors.len() {
            if alpha.iter().zip(&self.vectors[k]).all(|(x, y)| x >= y) {
                let old = self.remove(k);
                if !protect.contains(&self.graph.resolve(old)) {
                    self.graph.replace(old, node);
                }
            } else {
                k += 1;
            }
        }
        let k = self.vectors.len();
        self.vectors.push(alpha);
        self.actions.push(action);
        self.nodes.push(node);
        if k >= self.cap || self.vectors[0].len() != self.vectors[k].len() {
            self.rebuild((2 * self.cap).max(k + 1).max(BEST_CHUNK));
        } else {
            for (s, &x) in self.vectors[k].iter().enumerate() {
                self.by_state[s * self.cap + k] = x;
            }
        }
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
        self.rebuild(self.cap);
    }
}

#[cfg(test)]
#[path = "lower_tests.rs"]
mod tests;
