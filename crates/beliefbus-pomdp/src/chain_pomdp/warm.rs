//! Carrying a solution from a chain POMDP to its refinement (thesis
//! §4.5.2 proposes warm starts; "this was not implemented in the
//! examples").
//!
//! The previous α-vectors are moved to the new states by nearest neighbour
//! (each new state takes the value of the closest old one; actions keep
//! their indices because controls are only appended). A moved vector is
//! not the value of any plan of the new POMDP, so it cannot seed the lower
//! bound as it is. We make the moved set a finite-state controller: node k
//! takes action a_k and, on observation o, goes to the node σ(o) whose
//! vector is best at the belief ∝ Q(o|·); its value is the fixed point of
//!
//! ```text
//! (H V)_k(s) = R(s, a_k) + γ Σ_{s'} T(s'|s,a_k) Σ_o Q(o|s') V_{σ(o)}(s')
//! ```
//!
//! Start from V⁰ = moved − d/(1−γ), d = max_{k,s} (moved − H moved)⁺: then
//! V⁰ ≤ H V⁰ (H shifts constants by γ), so the iterates H^m V⁰ increase
//! towards the controller's value and every one is a lower bound of V* —
//! a valid initial lower bound for [`crate::solve`] whenever the loop
//! stops. σ is computed once, from the moved vectors, and then held: H is
//! the evaluation operator of one fixed controller, monotone and linear.
//! Re-choosing σ from each iterate (as an earlier version did) changes the
//! operator between iterations, so V ≤ H V no longer carries over and the
//! vectors can overstate their value; the greedy policy then picks a
//! carried vector whose plan it never follows — on the light-dark chains
//! it kept u = 0 for ever and scored 0.

use super::ChainPomdp;
use crate::policy::AlphaPolicy;
use crate::solver::graph::{self, Controller, PlanGraph};
use std::collections::HashMap;
use std::time::{Duration, Instant};

/// For each state of `next` (the absorbing one maps to the old absorbing
/// one), the index of the nearest state of `prev`.
pub fn nearest_map(prev: &ChainPomdp, next: &ChainPomdp) -> Vec<usize> {
    let (np, nn) = (prev.n_chain(), next.n_chain());
    let mut map: Vec<usize> = (0..nn)
        .map(|j| {
            let z = next.state(j);
            (0..np)
                .map(|i| {
                    let zi = prev.state(i);
                    let d2: f64 = z.iter().zip(zi).map(|(a, b)| (a - b) * (a - b)).sum();
                    (i, d2)
                })
                .fold((0, f64::INFINITY), |b, x| if x.1 < b.1 { x } else { b })
                .0
        })
        .collect();
    if next.pomdp.n_states() > nn && prev.pomdp.n_states() > np {
        map.push(np);
    }
    map
}

/// The α-vectors of `policy` (on `prev`) carried to `next` as a valid
/// lower bound (module doc), iterating H for at most `budget` or until the
/// largest change is below `tol`. Vectors whose action does not exist in
/// `next` are skipped.
pub fn carry(
    prev: &ChainPomdp,
    policy: &AlphaPolicy,
    next: &ChainPomdp,
    budget: Duration,
    tol: f64,
) -> Vec<(Vec<f64>, usize)> {
    let t0 = Instant::now();
    let p = &next.pomdp;
    let map = nearest_map(prev, next);
    let ns = p.n_states();
    let mut acts = Vec::new();
    let mut v: Vec<Vec<f64>> = Vec::new();
    for (alpha, &a) in policy.vectors.iter().zip(&policy.actions) {
        if a < p.n_actions() && map.len() == ns {
            v.push(map.iter().map(|&i| alpha[i]).collect());
            acts.push(a);
        }
    }
    if v.is_empty() {
        return Vec::new();
    }
    let no = p.n_obs();
    let mut h = vec![vec![0.0; ns]; v.len()];
    let mut w = vec![0.0; ns];
    // σ(o): best node at the belief ∝ Q(o|·) (the same Q for every action
    // of a chain POMDP; taken from the first action), fixed from here on.
    let q = &p.obs[0];
    let mut score = vec![vec![0.0; v.len()]; no];
    for s in 0..ns {
        let (os, qs) = q.row(s);
        for (&o, &qv) in os.iter().zip(qs) {
            for (k, vk) in v.iter().enumerate() {
                score[o as usize][k] += qv * vk[s];
            }
        }
    }
    let sigma: Vec<usize> = score
        .iter()
        .map(|sc| {
            sc.iter()
                .enumerate()
                .fold(
                    (0, f64::NEG_INFINITY),
                    |b, (k, &x)| if x > b.1 { (k, x) } else { b },
                )
                .0
        })
        .collect();
    let apply = |v: &[Vec<f64>], h: &mut [Vec<f64>], w: &mut [f64]| {
        for s in 0..ns {
            let (os, qs) = q.row(s);
            w[s] = os
                .iter()
                .zip(qs)
                .map(|(&o, &qv)| qv * v[sigma[o as usize]][s])
                .sum();
        }
        for (k, hk) in h.iter_mut().enumerate() {
            let a = acts[k];
            for (s, hs) in hk.iter_mut().enumerate() {
                *hs = p.backup_at(a, s, w);
            }
        }
    };
    apply(&v, &mut h, &mut w);
    let d = v
        .iter()
        .zip(&h)
        .flat_map(|(vk, hk)| vk.iter().zip(hk).map(|(x, y)| x - y))
        .fold(0.0f64, f64::max);
    let shift = d / (1.0 - p.discount);
    v.iter_mut().flatten().for_each(|x| *x -= shift);
    loop {
        apply(&v, &mut h, &mut w);
        // Keep each vector at least its previous iterate (the iterates
        // increase, so this only guards rounding).
        let mut change = 0.0f64;
        for (vk, hk) in v.iter_mut().zip(&h) {
            for (x, &y) in vk.iter_mut().zip(hk) {
                if y > *x {
                    change = change.max(y - *x);
                    *x = y;
                }
            }
        }
        if change < tol || t0.elapsed() >= budget {
            break;
        }
    }
    keep_useful(&next.pomdp.start, v, acts, MAX_CARRIED)
}

/// At most this many carried vectors: the solver evaluates every vector
/// at every belief it touches, and a previous solve kept unpruned can hold
/// thousands (a 75-state light-dark policy's slowed the 150-state solve so
/// much that its bounds hardly moved in 60 s and the policy scored 0).
pub const MAX_CARRIED: usize = 64;

/// The vectors best at b₀ or at some state (corner belief), then by value
/// at b₀, at most `cap` of them. Any subset of valid vectors is valid.
fn keep_useful(
    b0: &[f64],
    v: Vec<Vec<f64>>,
    acts: Vec<usize>,
    cap: usize,
) -> Vec<(Vec<f64>, usize)> {
    let at_b0: Vec<f64> = v
        .iter()
        .map(|vk| vk.iter().zip(b0).map(|(a, b)| a * b).sum())
        .collect();
    let argmax = |f: &dyn Fn(usize) -> f64| {
        (0..v.len())
            .map(|k| (k, f(k)))
            .fold((0, f64::NEG_INFINITY), |b, x| if x.1 > b.1 { x } else { b })
            .0
    };
    let mut keep = vec![argmax(&|k| at_b0[k])];
    let ns = v.first().map_or(0, Vec::len);
    for s in 0..ns {
        let k = argmax(&|k| v[k][s]);
        if !keep.contains(&k) {
            keep.push(k);
        }
    }
    keep[1..].sort_by(|&a, &b| at_b0[b].total_cmp(&at_b0[a]));
    keep.truncate(cap);
    let mut out: Vec<Option<(Vec<f64>, usize)>> = v.into_iter().zip(acts).map(Some).collect();
    keep.into_iter().filter_map(|k| out[k].take()).collect()
}

/// A solved chain POMDP: what [`carry_plan`] carries.
pub struct Solved<'a> {
    pub cp: &'a ChainPomdp,
    pub policy: &'a AlphaPolicy,
    /// The solver's plan graph and the node of each policy vector
    /// ([`crate::Solution::plan`], [`crate::Solution::plan_nodes`]).
    pub plan: &'a PlanGraph,
    pub plan_nodes: &'a [u32],
}

/// The previous solution's plans as a controller of `next` with certified
/// values ([`crate::solver::graph`]): the plan graph is kept node for
/// node (a node acts as before and moves to the same successor), each new
/// observation read as the nearest old observation point. The nodes are
/// taken breadth first from the policy's vectors in order of their value
/// at the previous b₀: all nodes of the first (best) plan, then others up
/// to `cap` in all; a successor left out goes to one
/// blind node repeating the action with the best worst-case reward. The
/// controller is evaluated on `next` for at most `budget` (or until the
/// change is below `tol`) from the previous vectors moved by nearest
/// state, then certified, so every value is a lower bound of `next`'s V*
/// and the best at b₀ is what the carried plans achieve there.
///
/// Unlike [`carry`], whose nodes choose their successor from the
/// observation alone, these plans keep their memory (go to the light,
/// then dead-reckon to the goal), so the refined problem starts from the
/// previous policy's behaviour rather than from a reactive one.
pub fn carry_plan(
    prev: &Solved<'_>,
    next: &ChainPomdp,
    cap: usize,
    budget: Duration,
    tol: f64,
) -> Controller {
    let t0 = Instant::now();
    let p = &next.pomdp;
    let plan = prev.plan;
    let map = nearest_map(prev.cp, next);
    if map.len() != p.n_states() || plan.is_empty() || cap == 0 {
        return Controller::default();
    }
    let obs_map = nearest_obs(prev.cp, next);
    let mut used: Vec<usize> = obs_map.clone();
    used.sort_unstable();
    used.dedup();
    // Roots: the policy's vectors by value at the previous b₀.
    let start = &prev.cp.pomdp.start;
    let mut roots: Vec<(f64, usize)> = prev
        .policy
        .vectors
        .iter()
        .enumerate()
        .filter(|(k, _)| prev.policy.actions[*k] < p.n_actions())
        .map(|(k, v)| (v.iter().zip(start).map(|(a, b)| a * b).sum(), k))
        .collect();
    roots.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut local: HashMap<u32, u32> = HashMap::new();
    let mut order: Vec<u32> = Vec::new();
    let mut queue = std::collections::VecDeque::new();
    'roots: for (r, &(_, k)) in roots.iter().enumerate() {
        let root = plan.resolve(prev.plan_nodes[k]);
        if local.contains_key(&root) {
            continue;
        }
        // The plan best at the previous b₀ is carried whole, whatever the
        // cap: cut off, its continuation falls to the blind leaf and the
        // carried value at b₀ collapses to the leaf's (seen at 150 → 300
        // light-dark states: a 271-node plan worth 416 carried with a cap
        // of 256 was worth 0 on its own chain).
        let limit = if r == 0 { usize::MAX } else { cap };
        if order.len() >= limit {
            break;
        }
        local.insert(root, order.len() as u32);
        order.push(root);
        queue.push_back(root);
        while let Some(n) = queue.pop_front() {
            for &o in &used {
                let m = plan.next(n, o);
                if plan.action(m) >= p.n_actions() || local.contains_key(&m) {
                    continue;
                }
                if order.len() >= limit {
                    break 'roots;
                }
                local.insert(m, order.len() as u32);
                order.push(m);
                queue.push_back(m);
            }
        }
    }
    // The leaf: a blind node with the best worst-case reward.
    let leaf = order.len() as u32;
    let leaf_action = (0..p.n_actions())
        .map(|a| (a, p.reward[a].iter().copied().fold(f64::INFINITY, f64::min)))
        .fold((0, f64::NEG_INFINITY), |b, x| if x.1 > b.1 { x } else { b })
        .0;
    let no = p.n_obs();
    let mut action: Vec<usize> = order.iter().map(|&n| plan.action(n)).collect();
    action.push(leaf_action);
    let mut succ = Vec::with_capacity(action.len() * no);
    for &n in &order {
        for &o in &obs_map {
            let m = plan.next(n, o);
            succ.push(local.get(&m).copied().unwrap_or(leaf));
        }
    }
    succ.extend(std::iter::repeat_n(leaf, no));
    // Start from the previous vectors where a node has one.
    let vector_of: HashMap<u32, usize> = prev
        .plan_nodes
        .iter()
        .enumerate()
        .map(|(k, &n)| (n, k))
        .collect();
    let ns = p.n_states();
    let mut init: Vec<Vec<f64>> = order
        .iter()
        .map(|n| match vector_of.get(n) {
            Some(&k) => map.iter().map(|&i| prev.policy.vectors[k][i]).collect(),
            None => vec![0.0; ns],
        })
        .collect();
    init.push(vec![0.0; ns]);
    let values = graph::evaluate(p, &action, &succ, init, tol, Some(t0 + budget));
    Controller {
        action,
        next: succ,
        values,
    }
}

/// For each observation point of `next`, the index of the nearest one of
/// `prev` (the points are appended as the problem grows, so the old ones
/// map to themselves).
pub fn nearest_obs(prev: &ChainPomdp, next: &ChainPomdp) -> Vec<usize> {
    next.observations
        .iter()
        .map(|y| {
            prev.observations
                .iter()
                .enumerate()
                .map(|(i, x)| (i, x.iter().zip(y).map(|(a, b)| (a - b) * (a - b)).sum()))
                .fold(
                    (0, f64::INFINITY),
                    |b, x: (usize, f64)| if x.1 < b.1 { x } else { b },
                )
                .0
        })
        .collect()
}

#[cfg(test)]
#[path = "warm_tests.rs"]
mod tests;
