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
                let (cols, vals) = p.trans[a].row(s);
                let ev: f64 = cols
                    .iter()
                    .zip(vals)
                    .map(|(&j, &t)| t * w[j as usize])
                    .sum();
                *hs = p.reward[a][s] + p.discount * ev;
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
