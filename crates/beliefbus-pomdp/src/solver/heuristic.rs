//! Lower-bound vectors from open-loop plans guided by the MDP's Q-values
//! (a heuristic-policy initialisation of Γ, in the spirit of the
//! blind-policy bound of Hauskrecht 2000, §7, and SARSOP's initial lower
//! bound, Kurniawati et al. 2008, §5).
//!
//! Blind policies repeat one action from every state. Problems whose
//! reward must be reached by a sequence of different actions (walk to a
//! goal, then declare) leave them far below V*, and point-based backups
//! only improve Γ at the beliefs a trial happens to visit. For every
//! state s this adds the value of one plan that ignores observations:
//!
//! * predict `d_0 = e_s`, `d_{t+1} = d_t T_{a_t}` with
//!   `a_t = argmax_a Σ_s d_t(s) Q_MDP(s,a)` (QMDP's action on the
//!   open-loop prediction), for t < H;
//! * its value from s if it switches at step t to repeating action a for
//!   ever is `Σ_{k<t} γ^k d_k·R_{a_k} + γ^t d_t·β_a` (β_a the blind
//!   vector of a); keep the best (t ≥ 1, a);
//! * the plan's α-vector follows backwards from `α_t = β_a`:
//!   `α_k = R_{a_k} + γ T_{a_k} α_{k+1}`.
//!
//! Every β_a is iterated from below its fixed point, and the backward step
//! is monotone, so each α is below the value of its plan from every state:
//! a valid lower bound whatever Q guided it. Observations are ignored, so
//! the plan is a chain of nodes whose successors are the same for every
//! observation, ending in a blind loop.

use crate::model::Pomdp;
use std::collections::HashSet;
use std::time::Instant;

/// One open-loop plan: `prefix` then `final_action` for ever, and the
/// lower bound of its value from every state.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenLoopPlan {
    pub prefix: Vec<usize>,
    pub final_action: usize,
    pub alpha: Vec<f64>,
}

/// `out = d T_a` for a dense `d` (`out` overwritten).
fn propagate(p: &Pomdp, a: usize, d: &[f64], support: &[u32], out: &mut [f64]) {
    out.iter_mut().for_each(|x| *x = 0.0);
    for &s in support {
        let w = d[s as usize];
        let (cols, vals) = p.trans[a].row(s as usize);
        for (&j, &t) in cols.iter().zip(vals) {
            out[j as usize] += w * t;
        }
    }
}

fn dot(d: &[f64], support: &[u32], v: &[f64]) -> f64 {
    support.iter().map(|&s| d[s as usize] * v[s as usize]).sum()
}

/// The open-loop plans of the module doc from every state, up to `horizon`
/// steps before the blind loop, with distinct (prefix, final action);
/// stops early at `deadline` (the plans found so far are kept). `q` are
/// Q-values guiding the actions (any: the result is a lower bound either
/// way), `blind[a]` a lower bound of repeating a from every state.
pub fn open_loop_plans(
    p: &Pomdp,
    q: &[Vec<f64>],
    blind: &[Vec<f64>],
    horizon: usize,
    deadline: Option<Instant>,
) -> Vec<OpenLoopPlan> {
    let (ns, na) = (p.n_states(), p.n_actions());
    let g = p.discount;
    let mut d = vec![0.0; ns];
    let mut next = vec![0.0; ns];
    let mut support: Vec<u32> = Vec::new();
    let mut seen: HashSet<(Vec<usize>, usize)> = HashSet::new();
    let mut plans = Vec::new();
    for s0 in 0..ns {
        if deadline.is_some_and(|t| Instant::now() >= t) {
            break;
        }
        d.iter_mut().for_each(|x| *x = 0.0);
        d[s0] = 1.0;
        support.clear();
        support.push(s0 as u32);
        let mut prefix = Vec::new();
        let mut gained = 0.0;
        let mut disc = 1.0;
        // The best switch so far: (value from s0, steps, final action);
        // t = 0 is a blind policy, already in Γ.
        let mut best: Option<(f64, usize, usize)> = None;
        let mut start_best = f64::NEG_INFINITY;
        for bl in blind {
            start_best = start_best.max(bl[s0]);
        }
        for _ in 0..horizon {
            let a = (0..na)
                .map(|a| (a, dot(&d, &support, &q[a])))
                .fold((0, f64::NEG_INFINITY), |b, x| if x.1 > b.1 { x } else { b })
                .0;
            gained += disc * dot(&d, &support, &p.reward[a]);
            propagate(p, a, &d, &support, &mut next);
            std::mem::swap(&mut d, &mut next);
            support.clear();
            support.extend((0..ns as u32).filter(|&s| d[s as usize] != 0.0));
            disc *= g;
            prefix.push(a);
            for (fa, bl) in blind.iter().enumerate() {
                let v = gained + disc * dot(&d, &support, bl);
                if v > best.map_or(start_best, |b| b.0) {
                    best = Some((v, prefix.len(), fa));
                }
            }
        }
        let Some((_, t, fa)) = best else { continue };
        prefix.truncate(t);
        if !seen.insert((prefix.clone(), fa)) {
            continue;
        }
        let alpha = backward(p, &prefix, &blind[fa]);
        plans.push(OpenLoopPlan {
            prefix,
            final_action: fa,
            alpha,
        });
    }
    plans
}

/// `α_k = R_{a_k} + γ T_{a_k} α_{k+1}` from `α_t = last` (module doc).
pub fn backward(p: &Pomdp, prefix: &[usize], last: &[f64]) -> Vec<f64> {
    let mut alpha = last.to_vec();
    let mut out = vec![0.0; alpha.len()];
    for &a in prefix.iter().rev() {
        for (s, o) in out.iter_mut().enumerate() {
            *o = p.backup_at(a, s, &alpha);
        }
        std::mem::swap(&mut alpha, &mut out);
    }
    alpha
}

#[cfg(test)]
#[path = "heuristic_tests.rs"]
mod tests;
