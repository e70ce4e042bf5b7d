//! The lower bound's plans as a finite-state controller (a policy graph),
//! and its exact evaluation on any POMDP with the same actions.
//!
//! Every α-vector of the lower bound is the value of a plan: a point-based
//! backup (Pineau et al. 2003, eq. 7) makes
//!
//! ```text
//! α(s) = R(s,a) + γ Σ_{s'} T(s'|s,a) Σ_o O(o|s',a) α_{σ(o)}(s')
//! ```
//!
//! so node k acts a_k and on observation o moves to the node σ_k(o) of the
//! vector chosen for o. [`PlanGraph`] records this for every vector the
//! solver keeps; when a new vector dominates an old one pointwise the old
//! node is redirected to the new one (the plan that continues with a
//! dominating vector is worth at least as much).
//!
//! Any such graph is a controller of every POMDP with the same actions
//! (observations are mapped onto the graph's), so its value there is a
//! lower bound of that POMDP's V*. [`evaluate`] computes it:
//!
//! ```text
//! (H V)_k(s) = R(s,a_k) + γ Σ_{s'} T(s'|s,a_k) Σ_o O(o|s',a_k) V_{σ_k(o)}(s')
//! ```
//!
//! is the controller's evaluation operator, a γ-contraction. From any start
//! the iterates converge to its fixed point; at the end,
//! `W = V − d/(1−γ)` with `d = max_{k,s} (V − H V)⁺` satisfies
//! `W ≤ H W` (H shifts constants by γ), so `W ≤ Hᵐ W → V_graph`: W is a
//! certified lower bound of the controller's value whenever the loop stops,
//! and equals it to within `d/(1−γ)` once converged.

use crate::model::Pomdp;
use std::time::Instant;

/// Nodes with an action and a successor per observation.
#[derive(Clone, Debug, Default)]
pub struct PlanGraph {
    n_obs: usize,
    action: Vec<u32>,
    next: Vec<u32>,
    /// A node whose vector was dominated points at the dominating node's
    /// (itself otherwise).
    redirect: Vec<u32>,
}

impl PlanGraph {
    pub fn new(n_obs: usize) -> Self {
        PlanGraph {
            n_obs,
            ..Default::default()
        }
    }

    pub fn n_obs(&self) -> usize {
        self.n_obs
    }

    pub fn len(&self) -> usize {
        self.action.len()
    }

    pub fn is_empty(&self) -> bool {
        self.action.is_empty()
    }

    /// Adds a node acting `action` and moving to `next[o]` on o.
    pub fn push(&mut self, action: usize, next: &[u32]) -> u32 {
        debug_assert_eq!(next.len(), self.n_obs);
        let id = self.action.len() as u32;
        self.action.push(action as u32);
        self.next.extend_from_slice(next);
        self.redirect.push(id);
        id
    }

    /// Adds a node that repeats `action` whatever it observes (a blind
    /// policy).
    pub fn push_loop(&mut self, action: usize) -> u32 {
        let id = self.action.len() as u32;
        self.action.push(action as u32);
        self.next.extend(std::iter::repeat_n(id, self.n_obs));
        self.redirect.push(id);
        id
    }

    /// Sends everything that continues with `old` to `by` instead.
    pub fn replace(&mut self, old: u32, by: u32) {
        if old != by {
            self.redirect[old as usize] = by;
        }
    }

    /// The node `k` stands for after redirects.
    pub fn resolve(&self, mut k: u32) -> u32 {
        while self.redirect[k as usize] != k {
            k = self.redirect[k as usize];
        }
        k
    }

    pub fn action(&self, k: u32) -> usize {
        self.action[k as usize] as usize
    }

    /// The successor of node `k` on observation `o`, after redirects.
    pub fn next(&self, k: u32, o: usize) -> u32 {
        self.resolve(self.next[k as usize * self.n_obs + o])
    }
}

/// A controller for a particular POMDP with its certified values: node k
/// acts `action[k]`, moves to `next[k·|O| + o]` on o, and is worth at least
/// `values[k]` from every state.
#[derive(Clone, Debug, Default)]
pub struct Controller {
    pub action: Vec<usize>,
    pub next: Vec<u32>,
    pub values: Vec<Vec<f64>>,
}

impl Controller {
    pub fn len(&self) -> usize {
        self.action.len()
    }

    pub fn is_empty(&self) -> bool {
        self.action.is_empty()
    }
}

/// `H` of the module doc applied to node `k`, written into `out`; `w` is a
/// buffer of |S| entries.
fn apply_node(
    p: &Pomdp,
    action: usize,
    next: &[u32],
    v: &[Vec<f64>],
    w: &mut [f64],
    out: &mut [f64],
) {
    let q = &p.obs[action];
    for (s2, ws) in w.iter_mut().enumerate() {
        let (os, qs) = q.row(s2);
        *ws = os
            .iter()
            .zip(qs)
            .map(|(&o, &qv)| qv * v[next[o as usize] as usize][s2])
            .sum();
    }
    let t = &p.trans[action];
    for (s, o) in out.iter_mut().enumerate() {
        let (cols, vals) = t.row(s);
        let ev: f64 = cols
            .iter()
            .zip(vals)
            .map(|(&j, &pt)| pt * w[j as usize])
            .sum();
        *o = p.reward[action][s] + p.discount * ev;
    }
}

/// A guard against a `tol` below the rounding of the values.
const MAX_SWEEPS: usize = 1_000_000;

/// The controller `(action, next)` evaluated on `p` from `start` (module
/// doc): in-place sweeps until the largest change is below `tol` or
/// `deadline`, then the certificate shift. `next` holds |O(p)| successors
/// per node, indices into the controller.
pub fn evaluate(
    p: &Pomdp,
    action: &[usize],
    next: &[u32],
    start: Vec<Vec<f64>>,
    tol: f64,
    deadline: Option<Instant>,
) -> Vec<Vec<f64>> {
    let ns = p.n_states();
    let no = p.n_obs();
    let mut v = start;
    let mut w = vec![0.0; ns];
    let mut out = vec![0.0; ns];
    for _ in 0..MAX_SWEEPS {
        let mut change = 0.0f64;
        for k in 0..v.len() {
            apply_node(
                p,
                action[k],
                &next[k * no..(k + 1) * no],
                &v,
                &mut w,
                &mut out,
            );
            for (x, &y) in v[k].iter_mut().zip(&out) {
                change = change.max((y - *x).abs());
                *x = y;
            }
        }
        if change < tol || deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
    }
    // One full (Jacobi) application for the certificate.
    let mut d = 0.0f64;
    for k in 0..v.len() {
        apply_node(
            p,
            action[k],
            &next[k * no..(k + 1) * no],
            &v,
            &mut w,
            &mut out,
        );
        for (x, y) in v[k].iter().zip(&out) {
            d = d.max(x - y);
        }
    }
    let shift = d / (1.0 - p.discount);
    v.iter_mut().flatten().for_each(|x| *x -= shift);
    v
}

/// The nodes reachable from `start` (after redirects) as a compact
/// controller: `(order, action, next)` where `order[i]` is the graph node
/// of controller node i (`order[0] = start`) and `next` indexes the
/// controller.
pub fn reachable(plan: &PlanGraph, start: u32) -> (Vec<u32>, Vec<usize>, Vec<u32>) {
    let start = plan.resolve(start);
    let mut local = std::collections::HashMap::from([(start, 0u32)]);
    let mut order = vec![start];
    let mut k = 0;
    while k < order.len() {
        let n = order[k];
        for o in 0..plan.n_obs() {
            let m = plan.next(n, o);
            if let std::collections::hash_map::Entry::Vacant(e) = local.entry(m) {
                e.insert(order.len() as u32);
                order.push(m);
            }
        }
        k += 1;
    }
    let action = order.iter().map(|&n| plan.action(n)).collect();
    let next = order
        .iter()
        .flat_map(|&n| (0..plan.n_obs()).map(move |o| plan.next(n, o)))
        .map(|m| local[&m])
        .collect();
    (order, action, next)
}
