//! What a light-dark plan is worth off its own chain: the plan's
//! finite-state controller run in the continuous light-dark dynamics
//!
//! ```text
//! x_{k+1} = clamp(x_k + u h + σ √h ξ),  ξ ~ N(0, I),   o_k ~ Q(o | x_{k+1}) ∝ p(o | x_{k+1})
//! ```
//!
//! with the plan's own decision period h and observation points (the
//! chain POMDP's Q extended from the chain states to every x), and the
//! terminal action paying ±1000 by the true x. This is the value a chain
//! approximates; it needs no second chain, so it tells whether a plan lost
//! value when carried or never had it off its chain.

use super::{Boxes, LightDarkObs};
use crate::rng::{self};
use beliefbus_pomdp::chain_pomdp::{ChainPomdp, ObservationModel};
use beliefbus_pomdp::solver::graph;
use beliefbus_pomdp::Solution;
use rand::RngExt;
use rand_distr::StandardNormal;

/// A controller: node k acts `action[k]` and moves to `next[k·|O| + o]`.
pub struct Fsc {
    pub action: Vec<usize>,
    pub next: Vec<u32>,
    pub n_obs: usize,
}

impl Fsc {
    /// The plan behind the solution's V̲(b₀) (node 0 is its start).
    pub fn of_solution(cp: &ChainPomdp, sol: &Solution) -> Fsc {
        let (k, _) = sol.policy.best_dense(&cp.pomdp.start);
        let (_, action, next) = graph::reachable(&sol.plan, sol.plan_nodes[k]);
        Fsc {
            action,
            next,
            n_obs: cp.pomdp.n_obs(),
        }
    }
}

/// The continuous problem: dynamics, observation model, goal and b₀.
pub struct Continuous<'a> {
    pub sigma: f64,
    pub obs: &'a LightDarkObs,
    pub goal: &'a Boxes,
    pub start_mean: [f64; 2],
    pub start_std: f64,
}

/// Mean discounted reward (and its standard error) of `fsc` from node 0
/// in the continuous problem, acting every `cp.period` with `cp`'s
/// controls, observation points and discount; `runs` seeded runs of at
/// most `horizon` decisions.
pub fn simulate_continuous(
    cp: &ChainPomdp,
    fsc: &Fsc,
    c: &Continuous<'_>,
    runs: usize,
    horizon: usize,
    seed: u64,
) -> (f64, f64) {
    let h = cp.period;
    let g = cp.pomdp.discount;
    let pts = &cp.observations;
    let mut w = vec![0.0; pts.len()];
    let mut ret = Vec::with_capacity(runs);
    for run in 0..runs {
        let mut rng = rng::stream(seed, run as u64);
        let mut x = [0.0; 2];
        for (i, xi) in x.iter_mut().enumerate() {
            let v = c.start_mean[i] + c.start_std * rng.sample::<f64, _>(StandardNormal);
            *xi = v.clamp(-2.0, 2.0);
        }
        let (mut total, mut disc, mut node) = (0.0, 1.0, 0usize);
        for _ in 0..horizon {
            let a = fsc.action[node];
            let Some(u) = cp.control(a) else {
                total += disc * if c.goal.contains(&x) { 1000.0 } else { -1000.0 };
                break;
            };
            total += disc * cp.pomdp.reward[a][0];
            for i in 0..2 {
                let v = x[i] + u[i] * h + c.sigma * h.sqrt() * rng.sample::<f64, _>(StandardNormal);
                x[i] = v.clamp(-2.0, 2.0);
            }
            let mut lmax = f64::NEG_INFINITY;
            for (wj, y) in w.iter_mut().zip(pts) {
                *wj = c.obs.log_likelihood(&x, y);
                lmax = lmax.max(*wj);
            }
            let mut sum = 0.0;
            for wj in w.iter_mut() {
                *wj = (*wj - lmax).exp();
                sum += *wj;
            }
            let mut r = rng.random::<f64>() * sum;
            let mut o = w.len() - 1;
            for (j, &wj) in w.iter().enumerate() {
                if r < wj {
                    o = j;
                    break;
                }
                r -= wj;
            }
            node = fsc.next[node * fsc.n_obs + o] as usize;
            disc *= g;
        }
        ret.push(total);
    }
    let n = runs as f64;
    let mean = ret.iter().sum::<f64>() / n;
    let var = ret.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

/// Diagnostic rows for one refinement `prev → cur`: the previous plan's
/// value on its own chain (certified and simulated), in the continuous
/// problem, carried onto itself and onto `cur`; and the current plan's
/// value in the continuous problem.
pub fn diagnose(
    prev: (&ChainPomdp, &Solution),
    cur: (&ChainPomdp, &Solution),
    carried_b0: Option<f64>,
    s: &super::Setting,
    runs: usize,
    seed: u64,
) -> Vec<super::Row> {
    use super::warm;
    use beliefbus_pomdp::{simulate_plan, SimulateOptions};
    use std::time::Duration;
    let light = super::light_2d();
    let goal = super::goal_2d();
    let obs = LightDarkObs { light, eps: s.eps };
    let c = Continuous {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start_mean: [-1.5, -0.5],
        start_std: 0.5,
    };
    let (pcp, psol) = prev;
    let (ccp, csol) = cur;
    let hz = |cp: &ChainPomdp| beliefbus_pomdp::simulate::horizon(&cp.pomdp, 1e-2);
    let fp = Fsc::of_solution(pcp, psol);
    let fc = Fsc::of_solution(ccp, csol);
    let (vp, vp_se) = simulate_continuous(pcp, &fp, &c, runs, hz(pcp), seed);
    let (vc, vc_se) = simulate_continuous(ccp, &fc, &c, runs, hz(ccp), seed);
    let sp = simulate_plan(
        &pcp.pomdp,
        psol,
        &SimulateOptions {
            runs,
            seed,
            precision: 1e-2,
            threads: 1,
        },
    )
    .map(|r| r.result.mean)
    .unwrap_or(f64::NAN);
    let best_at = |cp: &ChainPomdp, ctl: &graph::Controller| {
        ctl.values
            .iter()
            .map(|v| {
                v.iter()
                    .zip(&cp.pomdp.start)
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
            })
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let solved = warm::Solved {
        cp: pcp,
        policy: &psol.policy,
        plan: &psol.plan,
        plan_nodes: &psol.plan_nodes,
    };
    let mut self_carry = Vec::new();
    for cap in [256usize, 4096] {
        let ctl = warm::carry_plan(&solved, pcp, cap, Duration::from_secs(20), 1e-3);
        self_carry.push(best_at(pcp, &ctl));
    }
    let big = warm::carry_plan(&solved, ccp, 4096, Duration::from_secs(20), 1e-3);
    let (d_mean, d_lo, d_hi, d_across) = drift_fidelity(ccp, ccp.offset + 2);
    vec![super::Row::new("carry-check")
        .num("drift_along", d_mean)
        .num("drift_along_p10", d_lo)
        .num("drift_along_p90", d_hi)
        .num("drift_across", d_across)
        .int("states", ccp.n_chain() as u64)
        .int("prev_states", pcp.n_chain() as u64)
        .num("prev_period_s", pcp.period)
        .num("period_s", ccp.period)
        .int("prev_plan_nodes", fp.action.len() as u64)
        .int("plan_nodes", fc.action.len() as u64)
        .num("prev_lower_b0", psol.lower)
        .num("prev_plan_sim_chain", sp)
        .num("prev_plan_continuous", vp)
        .num("prev_plan_continuous_se", vp_se)
        .num("plan_continuous", vc)
        .num("plan_continuous_se", vc_se)
        .num("self_carry_256", self_carry[0])
        .num("self_carry_4096", self_carry[1])
        .num("carried_b0_256", carried_b0.unwrap_or(f64::NAN))
        .num("carried_b0_4096", best_at(ccp, &big))]
}

/// How far the chain's mean move over one decision follows the control:
/// for control `a`, per chain state, the mean displacement E[Δz] over one
/// period projected on u (as a fraction of |u| h) and its component
/// across u (same units). Returns (mean along, 10 % and 90 % quantiles
/// along, mean |across|) over states whose move stays inside [−1.5, 1.5]².
pub fn drift_fidelity(cp: &ChainPomdp, a: usize) -> (f64, f64, f64, f64) {
    let Some(u) = cp.control(a) else {
        return (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
    };
    let un = u.iter().map(|v| v * v).sum::<f64>().sqrt();
    let step = un * cp.period;
    let mut along = Vec::new();
    let mut across = 0.0;
    for i in 0..cp.n_chain() {
        let z = cp.state(i);
        if z.iter()
            .zip(u)
            .any(|(x, v)| (x + v * cp.period).abs() > 1.5 || x.abs() > 1.5)
        {
            continue;
        }
        let (cols, vals) = cp.pomdp.trans[a].row(i);
        let mut m = [0.0; 2];
        for (&j, &p) in cols.iter().zip(vals) {
            if (j as usize) < cp.n_chain() {
                let zj = cp.state(j as usize);
                m[0] += p * (zj[0] - z[0]);
                m[1] += p * (zj[1] - z[1]);
            }
        }
        let al = (m[0] * u[0] + m[1] * u[1]) / un;
        let ac = (m[0] * u[1] - m[1] * u[0]) / un;
        along.push(al / step);
        across += ac.abs() / step;
    }
    if along.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
    }
    let k = along.len();
    let mean = along.iter().sum::<f64>() / k as f64;
    along.sort_by(f64::total_cmp);
    (mean, along[k / 10], along[(9 * k) / 10], across / k as f64)
}
