//! What a solved light-dark policy is worth in the continuous problem when
//! run the way the live `pomdp` controller runs it: the α-vector policy's
//! argmax at a belief over the chain's states that a Bayes filter tracks
//! from the real-valued measurements (thesis 000 §4.7.2; the chain filter of
//! §3 as the belief).
//!
//! ```text
//! truth:   x ← clamp(x + u δ_e + σ √δ_e ξ),  ξ ~ N(0, I)    (Euler–Maruyama, 16 steps of δ_e = h/16 per decision)
//! measure: y = x_{k+1} + G(x_{k+1}) v,  v ~ N(0, I),  G = ε in the light, 1/ε in the dark
//! filter:  b̄(z') = Σ_z b(z) T(z'|z, a_k),  b_{k+1}(z') ∝ b̄(z') p(y | z')     (ChainPomdp::update)
//! act:     a_k = action(argmax_α α·b_k)
//! reward:  Σ_k γ^k R(a_k) with R the chain POMDP's −|u|² h, and ±1000 by the true x at the terminal action
//! ```
//!
//! b₀ is the chain POMDP's own start; the true x₀ is drawn from the
//! continuous start distribution it discretises. The period h, the controls,
//! the discount and the control costs are the chain POMDP's, so the only
//! difference from the chain's own evaluation is that the truth and the
//! measurements are continuous — the value every size approximates, on one
//! yardstick. The filter keeps its prediction when every likelihood
//! underflows (as the live filter does).
//!
//! Run `i` draws from random stream `(seed, i)` — split into the start,
//! the dynamics noise and the measurement noise — so every size sees the
//! same x₀ and the same seeds (common random numbers). The Euler step
//! count is fixed ([`EULER_STEPS`], not the chain's K) so that two sizes
//! with the same period draw the same noise for the same decision: their
//! returns pair episode by episode ([`Outcome::returns`]).
//!
//! The box [−2, 2]^d is, for the truth, a wall ([`Edge::Wall`]: the clamp
//! above, as the moment rows clamp the mean), nothing ([`Edge::Open`]: x
//! moves freely; the chain's states still stop at the box) or a cliff
//! ([`Edge::Cliff`]: a path that reaches it — at a step's end, or between
//! steps with the Brownian bridge's probability exp(−2 a₀ a₁/(σ² δ_e)),
//! a₀, a₁ the distances to the edge at the step's ends — ends the episode
//! with −1000; x₀ is then drawn inside the box, not clamped onto it; the
//! chain POMDP of [`beliefbus_pomdp::chain_pomdp::cliff`]). A plan that
//! localises by pushing into a wall loses its fix without walls and dies
//! on a cliff; one that localises in the light does not (`wall_frac`).

use super::{goal_2d, light_2d, Boxes, LightDarkObs, Setting};
use crate::rng;
use beliefbus_pomdp::chain_pomdp::ChainPomdp;
use beliefbus_pomdp::AlphaPolicy;
use rand::RngExt;
use rand_distr::StandardNormal;

/// Euler–Maruyama steps per decision period of the continuous truth.
pub const EULER_STEPS: usize = 16;

/// What the box's edge is to the continuous truth (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Edge {
    Wall,
    Open,
    Cliff,
}

/// What moves the true state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Truth {
    /// dx = u dt + σ dw with the box's edge as given.
    Sde(Edge),
    /// The chain itself (x₀ ~ b₀ on the states, each period a draw from
    /// T(·|z, a)): the model the policy was solved for, so that the same
    /// filter and lookup can be checked where the policy is known to work.
    Chain,
}

/// The continuous start distribution (clamped to the domain [−2, 2]^d).
#[derive(Clone, Debug)]
pub enum Start {
    /// N(mean, std² I).
    Gaussian { mean: Vec<f64>, std: f64 },
    /// Uniform on [lo, hi]^d.
    Uniform { lo: f64, hi: f64 },
}

/// The continuous problem the chain POMDP discretises.
pub struct Problem<'a> {
    pub sigma: f64,
    pub obs: &'a LightDarkObs,
    pub goal: &'a Boxes,
    pub start: Start,
    pub truth: Truth,
}

/// Mean discounted reward with its standard error, and the fraction of
/// episodes that end with the terminal action inside the goal.
#[derive(Clone, Debug, PartialEq)]
pub struct Outcome {
    pub mean: f64,
    pub std_err: f64,
    pub goal_frac: f64,
    /// Episodes that took the terminal action at all.
    pub declared_frac: f64,
    /// Over the declared episodes: mean |x − c|_∞ from the true x to the
    /// nearest goal centre c, and mean |E_b[z] − x|_∞ of the belief's mean
    /// (whether the agent missed because it believed it was elsewhere).
    pub declare_dist: f64,
    pub belief_err: f64,
    /// Over the declared episodes: the fraction whose truth was in a light
    /// box at some decision before declaring (the plan localised in the
    /// light, or at least passed through it).
    pub lit_frac: f64,
    /// The fraction of episodes whose truth reached the box's edge (with
    /// walls: was clamped; without: left the box) by a move before
    /// declaring (or before the horizon, if it never declared).
    pub wall_frac: f64,
    /// The fraction of episodes ended by falling off a cliff edge.
    pub crash_frac: f64,
    /// Each episode's discounted return, in run order (for paired
    /// differences between policies evaluated with the same seed).
    pub returns: Vec<f64>,
    /// Each declared episode's end, in run order (for the trace).
    pub ends: Vec<End>,
}

/// Where one episode declared: the decision, the truth, the belief's mean,
/// its most probable state and its mass on the states inside the goal.
#[derive(Clone, Debug, PartialEq)]
pub struct End {
    pub run: usize,
    pub step: usize,
    pub x: Vec<f64>,
    pub belief_mean: Vec<f64>,
    pub map_state: usize,
    pub goal_mass: f64,
}

impl Outcome {
    /// The experiment's columns for this outcome: `continuous` ± s.e.,
    /// `goal_frac`, `declared_frac`, `declare_dist`, `belief_err`,
    /// `lit_frac`.
    pub fn columns(&self, row: super::Row) -> super::Row {
        row.num("continuous", self.mean)
            .num("continuous_se", self.std_err)
            .num("goal_frac", self.goal_frac)
            .num("declared_frac", self.declared_frac)
            .num("declare_dist", self.declare_dist)
            .num("belief_err", self.belief_err)
            .num("lit_frac", self.lit_frac)
            .num("wall_frac", self.wall_frac)
            .num("crash_frac", self.crash_frac)
    }

    /// Mean and standard error of the episode-by-episode difference
    /// `self − other` (common random numbers: both evaluated with the same
    /// seed and period); `None` if the run counts differ.
    pub fn paired_diff(&self, other: &Outcome) -> Option<(f64, f64)> {
        let n = self.returns.len();
        if n < 2 || other.returns.len() != n {
            return None;
        }
        let d: Vec<f64> = self
            .returns
            .iter()
            .zip(&other.returns)
            .map(|(a, b)| a - b)
            .collect();
        let mean = d.iter().sum::<f64>() / n as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        Some((mean, (var / n as f64).sqrt()))
    }
}

/// Runs `policy` (solved on `cp`) for `runs` seeded episodes of at most
/// `horizon` decisions in the continuous problem `p` (module doc).
pub fn evaluate(
    cp: &ChainPomdp,
    policy: &AlphaPolicy,
    p: &Problem<'_>,
    runs: usize,
    horizon: usize,
    seed: u64,
) -> Outcome {
    let d = cp.dim;
    let h = cp.period;
    let m = EULER_STEPS;
    let de = h / m as f64;
    let chain_truth = p.truth == Truth::Chain;
    let edge = match p.truth {
        Truth::Sde(e) => e,
        Truth::Chain => Edge::Wall,
    };
    let nc = cp.n_chain();
    let mut crashed = 0usize;
    let g = cp.pomdp.discount;
    let ns = cp.pomdp.n_states();
    let mut b = vec![0.0; ns];
    let mut next = vec![0.0; ns];
    let mut x = vec![0.0; d];
    let mut y = vec![0.0; d];
    let mut ret = Vec::with_capacity(runs);
    let mut ends = Vec::new();
    let (mut in_goal, mut declared) = (0usize, 0usize);
    let (mut dist, mut berr) = (0.0, 0.0);
    let (mut lit, mut wall) = (0usize, 0usize);
    let on_edge = |x: &[f64]| x.iter().any(|v| v.abs() >= 2.0);
    let inf_norm = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max)
    };
    for run in 0..runs {
        let mut r_start = rng::stream(seed, 3 * run as u64);
        let mut r_dyn = rng::stream(seed, 3 * run as u64 + 1);
        let mut r_obs = rng::stream(seed, 3 * run as u64 + 2);
        for (i, xi) in x.iter_mut().enumerate() {
            let v = match &p.start {
                Start::Gaussian { mean, std } => {
                    let mut v = mean[i] + std * r_start.sample::<f64, _>(StandardNormal);
                    // On a cliff the start is the Gaussian truncated to the
                    // box (as b₀ on the chain's states), not clamped onto it.
                    while edge == Edge::Cliff && v.abs() >= 2.0 {
                        v = mean[i] + std * r_start.sample::<f64, _>(StandardNormal);
                    }
                    v
                }
                Start::Uniform { lo, hi } => r_start.random_range(*lo..*hi),
            };
            *xi = v.clamp(-2.0, 2.0);
        }
        let mut z = 0usize;
        if chain_truth {
            z = draw(&cp.pomdp.start, r_start.random::<f64>());
            x.copy_from_slice(cp.state(z));
        }
        // Only the moves count: x₀ is clamped into the box (≈ 16 % of the
        // 2-D starts lie on the edge x₁ = −2) before any plan acts.
        let mut touched = false;
        b.copy_from_slice(&cp.pomdp.start);
        let (mut total, mut disc) = (0.0, 1.0);
        let mut seen_light = p.obs.light.contains(&x);
        for step in 0..horizon {
            let a = policy.action(&b);
            let Some(u) = cp.control(a) else {
                declared += 1;
                lit += usize::from(seen_light);
                dist += p
                    .goal
                    .0
                    .iter()
                    .map(|(c, _)| inf_norm(c, &x))
                    .fold(f64::INFINITY, f64::min);
                // y is free at the end of the episode: the belief's mean.
                for (i, yi) in y.iter_mut().enumerate() {
                    *yi = (0..cp.n_chain()).map(|z| b[z] * cp.state(z)[i]).sum();
                }
                berr += inf_norm(&y, &x);
                let map_state = (0..nc).fold(0, |m, z| if b[z] > b[m] { z } else { m });
                ends.push(End {
                    run,
                    step,
                    x: x.clone(),
                    belief_mean: y.clone(),
                    map_state,
                    goal_mass: (0..nc)
                        .filter(|&z| p.goal.contains(cp.state(z)))
                        .map(|z| b[z])
                        .sum(),
                });
                let hit = p.goal.contains(&x);
                in_goal += usize::from(hit);
                total += disc * if hit { 1000.0 } else { -1000.0 };
                break;
            };
            // The chain truth pays the chain's reward (on a cliff its
            // expected penalty); the SDE pays the control cost, and the
            // penalty only if it falls.
            total += disc
                * if chain_truth {
                    cp.pomdp.reward[a][z]
                } else {
                    -u.iter().map(|v| v * v).sum::<f64>() * h
                };
            if chain_truth {
                let (cols, vals) = cp.pomdp.trans[a].row(z);
                z = cols[draw(vals, r_dyn.random::<f64>())] as usize;
                if z >= nc {
                    // Fallen off (a cliff row's absorbing end).
                    crashed += 1;
                    touched = true;
                    break;
                }
                x.copy_from_slice(cp.state(z));
                touched |= on_edge(&x);
            }
            if !chain_truth {
                touched |= sde_period(&mut x, u, p.sigma, de, m, edge, &mut r_dyn);
                if touched && edge == Edge::Cliff {
                    crashed += 1;
                    total += disc * -1000.0;
                    break;
                }
            }
            seen_light |= p.obs.light.contains(&x);
            let s = if p.obs.light.contains(&x) {
                p.obs.eps
            } else {
                1.0 / p.obs.eps
            };
            for (yi, xi) in y.iter_mut().zip(&x) {
                *yi = xi + s * r_obs.sample::<f64, _>(StandardNormal);
            }
            if cp.update(&b, a, &y, p.obs, &mut next) {
                std::mem::swap(&mut b, &mut next);
            } else {
                // Every likelihood underflowed: keep the prediction.
                let sum: f64 = next.iter().sum();
                if sum > 0.0 {
                    for (bi, pi) in b.iter_mut().zip(&next) {
                        *bi = pi / sum;
                    }
                }
            }
            disc *= g;
        }
        wall += usize::from(touched);
        ret.push(total);
    }
    let n = runs as f64;
    let mean = ret.iter().sum::<f64>() / n;
    let var = ret.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    Outcome {
        mean,
        std_err: (var / n).sqrt(),
        goal_frac: in_goal as f64 / n,
        declared_frac: declared as f64 / n,
        declare_dist: dist / declared.max(1) as f64,
        belief_err: berr / declared.max(1) as f64,
        lit_frac: lit as f64 / declared.max(1) as f64,
        wall_frac: wall as f64 / n,
        crash_frac: crashed as f64 / n,
        returns: ret,
        ends,
    }
}

/// The policy's value in the continuous `dim`-D problem
/// ([`evaluate`]): 1-D from x₀ ~ U(−2, 2) (b₀ uniform on the
/// grid), 2-D from N((−1.5, −0.5), 0.5² I).
pub fn value(
    cp: &ChainPomdp,
    policy: &AlphaPolicy,
    s: &Setting,
    dim: usize,
    runs: usize,
    seed: u64,
    truth: Truth,
) -> Outcome {
    let (light, goal, start) = if dim == 1 {
        (
            Boxes(vec![(vec![0.9], 0.1)]),
            Boxes(vec![(vec![-0.9], 0.1)]),
            Start::Uniform { lo: -2.0, hi: 2.0 },
        )
    } else {
        (
            light_2d(),
            goal_2d(),
            Start::Gaussian {
                mean: vec![-1.5, -0.5],
                std: 0.5,
            },
        )
    };
    let obs = LightDarkObs { light, eps: s.eps };
    let p = Problem {
        sigma: s.sigma,
        obs: &obs,
        goal: &goal,
        start,
        truth,
    };
    let horizon = beliefbus_pomdp::simulate::horizon(&cp.pomdp, 1e-2);
    evaluate(cp, policy, &p, runs, horizon, seed)
}

/// `steps` Euler–Maruyama steps of dx = u dt + σ dw of length `de`, each
/// clamped to [−2, 2] for [`Edge::Wall`]; true if any step reached the
/// edge (|x_i| ≥ 2 before the clamp). For [`Edge::Cliff`] a path between
/// two steps inside also reaches it with the Brownian bridge's probability
/// (module doc), and the period stops there (true: fallen).
pub fn sde_period(
    x: &mut [f64],
    u: &[f64],
    sigma: f64,
    de: f64,
    steps: usize,
    edge: Edge,
    rng: &mut impl rand::Rng,
) -> bool {
    let mut touched = false;
    let s2 = sigma * sigma * de;
    for _ in 0..steps {
        for (xi, ui) in x.iter_mut().zip(u) {
            let v = *xi + ui * de + sigma * de.sqrt() * rng.sample::<f64, _>(StandardNormal);
            touched |= v.abs() >= 2.0;
            if edge == Edge::Cliff && !touched {
                let bridge = (-2.0 * (2.0 - *xi) * (2.0 - v) / s2).exp()
                    + (-2.0 * (2.0 + *xi) * (2.0 + v) / s2).exp();
                touched |= rng.random::<f64>() < bridge;
            }
            *xi = if edge == Edge::Wall {
                v.clamp(-2.0, 2.0)
            } else {
                v
            };
        }
        if touched && edge == Edge::Cliff {
            return true;
        }
    }
    touched
}

/// The index where the cumulative sum of `w` passes `u`·Σw.
fn draw(w: &[f64], u: f64) -> usize {
    let mut r = u * w.iter().sum::<f64>();
    for (j, &wj) in w.iter().enumerate() {
        if r < wj {
            return j;
        }
        r -= wj;
    }
    w.len() - 1
}
