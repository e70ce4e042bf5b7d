//! A point-based anytime POMDP solver with both bounds at b₀.
//!
//! Heuristic search value iteration (HSVI2; Smith & Simmons, UAI 2005,
//! Alg. 1–2), the exploration rule SARSOP also builds on (Kurniawati, Hsu &
//! Lee, RSS 2008, §4):
//!
//! * a trial descends from b₀; at depth t it stops when the bound gap
//!   `V̄(b) − V̲(b) ≤ ε γ^{−t}`, otherwise it takes the action with the best
//!   upper bound `a* = argmax_a Q̄(b,a)` and the observation with the largest
//!   weighted excess gap `P(o|b,a*) (V̄ − V̲ − ε γ^{−(t+1)})(b^{a*,o})`;
//! * on the way back every belief of the trial gets a lower-bound α backup
//!   ([`lower`]) and an upper-bound sawtooth backup ([`upper`]);
//! * trials repeat until `V̄(b₀) − V̲(b₀) ≤ ε` (the precision) or the time
//!   budget ends; the bounds at b₀ are reported as they tighten. Each trial's
//!   ε is `max(precision, fraction × current gap at b₀)`
//!   ([`SolveOptions::trial_gap_fraction`]): while the gap is wide, HSVI2's
//!   fixed ε sends every trial ~log(gap/ε)/log(1/γ) steps deep (≈110 on
//!   Hallway), where backups barely move b₀; short trials tighten b₀ faster.
//!   With [`SolveOptions::follow_lower_every`] = k every k-th trial takes
//!   the lower bound's action instead of `a*` (the plan behind V̲, so that
//!   its beliefs are backed up too); the child rule is unchanged.
//!
//! Lower bound: α-vectors from blind policies and from open-loop plans
//! guided by the MDP's Q-values ([`heuristic`]), pruned by pointwise dominance
//! and by the sampled beliefs; every vector's plan is recorded ([`graph`]),
//! so a solution can be carried to another model as a controller and
//! evaluated there exactly; at the end V̲(b₀) is raised to the exact value
//! of the plan behind it ([`add_plan_value`]). Upper bound: FIB started from the fully
//! observed MDP's Q-values, then sawtooth points. Beliefs and model
//! matrices are sparse throughout.

pub mod graph;
pub mod heuristic;
pub mod lower;
pub mod upper;

#[cfg(test)]
pub(crate) mod dense_eval;
#[cfg(test)]
mod plan_value_tests;
#[cfg(test)]
pub(crate) mod sparse_eval;

use crate::belief::{Branch, SparseBelief, Updater};
use crate::model::Pomdp;
use crate::policy::AlphaPolicy;
use graph::{Controller, PlanGraph};
use lower::LowerBound;
use std::collections::HashSet;
use std::time::{Duration, Instant};
use thiserror::Error;
use upper::UpperBound;

/// Settings of [`solve`].
#[derive(Clone, Debug)]
pub struct SolveOptions {
    /// Stop when `V̄(b₀) − V̲(b₀) ≤ precision`.
    pub precision: f64,
    /// Stop after this much wall-clock time (`None`: only the precision).
    pub time_limit: Option<Duration>,
    /// Report progress at most this often (the first and last reports are
    /// always made; zero reports after every trial).
    pub report_interval: Duration,
    /// Each trial aims at a gap at b₀ of `max(precision, fraction × current
    /// gap)`: short trials while the gap is wide, HSVI2's fixed-ε trials
    /// once it is near the precision (0 = always the precision).
    pub trial_gap_fraction: f64,
    /// Threads for the upper-bound backups (1 = no threads spawned).
    pub threads: usize,
    /// Extra α-vectors (with their actions) added to the initial lower
    /// bound, e.g. a previous solution carried to a refined model. Each
    /// must be the value of a plan of `p` (see
    /// [`crate::chain_pomdp::warm`]), or the lower bound is no bound.
    pub initial_lower: Vec<(Vec<f64>, usize)>,
    /// A controller of `p` with certified values (e.g. a previous
    /// solution's plans carried to a refined model,
    /// [`crate::chain_pomdp::warm::carry_plan`]): its nodes join the plan
    /// graph and its values the lower bound, so V̲(b₀) starts at least at
    /// its best value at b₀ and the greedy policy can follow its plans.
    pub initial_controller: Option<Controller>,
    /// Posterior masses below this are dropped from the sampled beliefs
    /// (0 = exact). The lower bound stays a bound (its α-vectors are plan
    /// values whatever belief selected them); the upper bound at a
    /// truncated belief is off by at most the dropped mass times the
    /// reward range over 1 − γ.
    pub belief_flush: f64,
    /// Prune the lower bound by the sampled beliefs. Pruning keeps V̲(b₀)
    /// but can drop the vector a kept plan continues with at a branch
    /// belief that was never sampled; the greedy policy then no longer
    /// attains V̲ (seen on the light-dark chains: it stays in the light
    /// for ever). `false` keeps every non-dominated vector.
    pub prune_lower: bool,
    /// Steps of the open-loop plans added to the initial lower bound
    /// ([`heuristic`]; 0: blind policies only). Sound (every vector is
    /// checked against its plan's value in the tests), but off by
    /// default: on the standard problems and the 2-D light-dark chains
    /// they raise V̲ only at the start and do not shorten the solves
    /// (docs/pomdp.md has the figures).
    pub open_loop_horizon: usize,
    /// Divide each child's weighted excess by one more than the number of
    /// trials that already went into it (false: HSVI2's largest excess).
    pub spread_trials: bool,
    /// Every `k`-th trial (0: none) descends by the lower bound's action
    /// at each belief — the action of the best α-vector there, i.e. the
    /// plan behind V̲ — instead of the upper bound's, choosing the child by
    /// the same weighted-excess rule. The backups on its way back are the
    /// ordinary ones, so the bounds keep their meaning; what changes is
    /// which beliefs are backed up: those the current best plan reaches,
    /// where a backup can improve that plan (e.g. a plan carried from a
    /// coarser chain, whose beliefs the upper bound's trials may never
    /// visit).
    pub follow_lower_every: u32,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            precision: 1e-3,
            time_limit: None,
            report_interval: Duration::from_millis(500),
            trial_gap_fraction: 0.5,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            initial_lower: Vec::new(),
            initial_controller: None,
            belief_flush: 0.0,
            prune_lower: true,
            open_loop_horizon: 0,
            spread_trials: true,
            follow_lower_every: 0,
        }
    }
}

/// Bounds at b₀ during a solve.
#[derive(Clone, Debug, PartialEq)]
pub struct Progress {
    pub time_s: f64,
    pub lower: f64,
    pub upper: f64,
    pub trials: u64,
    pub alpha_vectors: usize,
    pub upper_points: usize,
}

/// The result of [`solve`].
#[derive(Clone, Debug)]
pub struct Solution {
    /// V̲(b₀): the policy's guaranteed value.
    pub lower: f64,
    /// V̄(b₀) ≥ V*(b₀).
    pub upper: f64,
    pub policy: AlphaPolicy,
    /// The plans behind the policy's vectors: vector k is the value of
    /// node `plan_nodes[k]` of `plan` ([`graph`]).
    pub plan: PlanGraph,
    pub plan_nodes: Vec<u32>,
    pub time_s: f64,
    pub trials: u64,
    /// Whether the precision was reached (else the time budget ended it).
    pub converged: bool,
}

/// Why [`solve`] refused a problem.
#[derive(Debug, Error, PartialEq)]
pub enum SolveError {
    /// Infinite-horizon bounds need γ < 1.
    #[error("discount {0} must be below 1 for the infinite-horizon solver")]
    Discount(f64),
    /// The precision must be a positive number.
    #[error("precision {0} must be positive")]
    Precision(f64),
    /// The trial gap fraction must be in [0, 1).
    #[error("trial gap fraction {0} must be in [0, 1)")]
    TrialGapFraction(f64),
    /// The initial controller does not fit the problem.
    #[error("initial controller: {0}")]
    Controller(String),
}

/// Checks that `c` is a controller of `p`.
fn check_controller(p: &Pomdp, c: &Controller) -> Result<(), SolveError> {
    let n = c.len();
    let bad = |m: String| Err(SolveError::Controller(m));
    if c.values.len() != n || c.next.len() != n * p.n_obs() {
        return bad(format!(
            "{n} nodes need {n} value vectors and {} successors",
            n * p.n_obs()
        ));
    }
    if c.action.iter().any(|&a| a >= p.n_actions()) {
        return bad(format!("an action is not below {}", p.n_actions()));
    }
    if c.next.iter().any(|&k| k as usize >= n) {
        return bad("a successor is not a node".into());
    }
    if c.values.iter().any(|v| v.len() != p.n_states()) {
        return bad(format!("a value vector is not of {} states", p.n_states()));
    }
    Ok(())
}

/// Solves `p` from its start belief (see the module doc), calling
/// `on_progress` as the bounds at b₀ tighten.
pub fn solve(
    p: &Pomdp,
    opts: &SolveOptions,
    mut on_progress: impl FnMut(&Progress),
) -> Result<Solution, SolveError> {
    if !(p.discount < 1.0) {
        return Err(SolveError::Discount(p.discount));
    }
    if !(opts.precision > 0.0) || !opts.precision.is_finite() {
        return Err(SolveError::Precision(opts.precision));
    }
    if !(0.0..1.0).contains(&opts.trial_gap_fraction) {
        return Err(SolveError::TrialGapFraction(opts.trial_gap_fraction));
    }
    if let Some(c) = &opts.initial_controller {
        check_controller(p, c)?;
    }
    let t0 = Instant::now();
    // The last tenth of the budget evaluates the plan behind V̲(b₀)
    // ([`add_plan_value`]).
    let search_limit = opts.time_limit.map(|l| l.mul_f64(0.9));
    let out_of_time = || search_limit.is_some_and(|l| t0.elapsed() >= l);
    let g = p.discount;
    let eps = opts.precision;
    let tol = eps * (1.0 - g) * 1e-2;
    let blind = lower::blind_vectors(p, tol, 100_000);
    let mut lb = LowerBound::from_blind(p, &blind);
    // FIB may take at most a quarter of the budget (it is O(|A|²) per
    // state and observation; stopping early keeps it an upper bound).
    let fib_deadline = opts.time_limit.map(|l| t0 + l / 4);
    let q_mdp = upper::mdp_q(p, tol, 100_000, fib_deadline);
    if opts.open_loop_horizon > 0 {
        // At most a twentieth of the budget: the plans found by then are
        // bounds already.
        let deadline = opts.time_limit.map(|l| Instant::now() + l / 20);
        for plan in heuristic::open_loop_plans(p, &q_mdp, &blind, opts.open_loop_horizon, deadline)
        {
            let mut node = lb.graph.push_loop(plan.final_action);
            for &a in plan.prefix.iter().rev() {
                node = lb.graph.push(a, &vec![node; p.n_obs()]);
            }
            lb.add(plan.alpha, plan.prefix[0], node);
        }
    }
    let mut ub = UpperBound::new(p, upper::fib_from(p, q_mdp, tol, 100_000, fib_deadline));
    // A plan's value at a corner e_s is at most V*(e_s) ≤ the FIB corner
    // value: a supplied vector above it anywhere is no plan's value, and
    // trusting it would let the solver stop on a false bound.
    // Supplied vectors without a plan are recorded as repeating their
    // action: the graph stays a controller (its later evaluation on
    // another model is exact whatever the node stands for).
    for (alpha, a) in &opts.initial_lower {
        if alpha.len() == p.n_states()
            && *a < p.n_actions()
            && alpha.iter().all(|x| x.is_finite())
            && ub.below_corners(alpha)
        {
            let node = lb.graph.push_loop(*a);
            lb.add(alpha.clone(), *a, node);
        }
    }
    if let Some(c) = &opts.initial_controller {
        let base = lb.graph.len() as u32;
        let no = p.n_obs();
        let mut next = vec![0u32; no];
        for k in 0..c.len() {
            for (x, &j) in next.iter_mut().zip(&c.next[k * no..(k + 1) * no]) {
                *x = base + j;
            }
            lb.graph.push(c.action[k], &next);
        }
        for k in 0..c.len() {
            let v = &c.values[k];
            if v.iter().all(|x| x.is_finite()) && ub.below_corners(v) {
                lb.add(v.clone(), c.action[k], base + k as u32);
            }
        }
    }
    let mut upd = Updater::new(p);
    upd.flush = opts.belief_flush;
    let b0 = SparseBelief::from_dense(&p.start);

    let mut samples: Vec<SparseBelief> = Vec::new();
    let mut seen: HashSet<Vec<u64>> = HashSet::new();
    let mut pruned_at = lb.vectors.len().max(16);
    let mut trials = 0u64;
    let mut visits: std::collections::HashMap<u64, u32> = std::collections::HashMap::new();
    let mut last_report: Option<Instant> = None;
    let mut report = |lb: &mut LowerBound, ub: &mut UpperBound, trials: u64, force: bool| {
        if force || last_report.is_none_or(|t| t.elapsed() >= opts.report_interval) {
            last_report = Some(Instant::now());
            on_progress(&Progress {
                time_s: t0.elapsed().as_secs_f64(),
                lower: lb.value(&b0),
                upper: ub.value(&b0),
                trials,
                alpha_vectors: lb.vectors.len(),
                upper_points: ub.n_points(),
            });
        }
    };
    report(&mut lb, &mut ub, 0, true);
    let mut converged = ub.value(&b0) - lb.value(&b0) <= eps;
    while !converged && !out_of_time() {
        // Each belief of the trial with its successors: the backward pass
        // backs up the same beliefs, so they are expanded once.
        let mut path: Vec<(SparseBelief, Vec<Vec<Branch>>)> = Vec::new();
        let mut b = b0.clone();
        let mut threshold = eps.max(opts.trial_gap_fraction * (ub.value(&b0) - lb.value(&b0)));
        let every = u64::from(opts.follow_lower_every);
        let follow_lower = every > 0 && trials % every == every - 1;
        loop {
            let branches = successors(p, &mut upd, &b);
            let (qs, child_upper) = ub.backup(p, &b, &branches, opts.threads);
            let (a_star, v_up) = argmax(&qs);
            ub.add(&b, v_up);
            let gap = ub.value(&b) - lb.value(&b);
            if gap <= threshold || out_of_time() {
                path.push((b, branches));
                break;
            }
            threshold /= g;
            let a_go = if follow_lower {
                lb.actions[lb.best(&b).0]
            } else {
                a_star
            };
            // The child with the largest weighted excess, divided by one
            // more than the trials that already descended into it
            // (`spread_trials`): a child whose bounds the trials could not
            // move hands the next trial to its siblings.
            let mut pick: Option<(usize, f64, u64)> = None;
            for (k, br) in branches[a_go].iter().enumerate() {
                let excess = br.prob * (child_upper[a_go][k] - lb.value(&br.belief) - threshold);
                if excess <= 0.0 {
                    continue;
                }
                let (score, h) = if opts.spread_trials {
                    let h = belief_hash(&br.belief);
                    let n = visits.get(&h).copied().unwrap_or(0);
                    (excess / (1.0 + n as f64), h)
                } else {
                    (excess, 0)
                };
                if pick.is_none_or(|(_, e, _)| score > e) {
                    pick = Some((k, score, h));
                }
            }
            let child = pick.map(|(k, _, h)| {
                if opts.spread_trials {
                    *visits.entry(h).or_insert(0) += 1;
                }
                branches[a_go][k].belief.clone()
            });
            path.push((b, branches));
            match child {
                Some(c) => b = c,
                None => break,
            }
        }
        for (b, branches) in path.iter().rev() {
            let (alpha, a, _, next) = lb.backup(p, b, branches);
            lb.add_plan(alpha, a, &next);
            let (qs, _) = ub.backup(p, b, branches, opts.threads);
            ub.add(b, argmax(&qs).1);
        }
        for (b, _) in path {
            if seen.insert(b.key()) {
                samples.push(b);
            }
        }
        trials += 1;
        if opts.prune_lower && lb.vectors.len() > 2 * pruned_at {
            lb.prune(samples.iter().chain(std::iter::once(&b0)));
            pruned_at = lb.vectors.len().max(16);
        }
        converged = ub.value(&b0) - lb.value(&b0) <= eps;
        report(&mut lb, &mut ub, trials, false);
    }
    if opts.prune_lower {
        lb.prune(samples.iter().chain(std::iter::once(&b0)));
    }
    let eval_deadline = opts
        .time_limit
        .map_or(Instant::now() + Duration::from_secs(10), |l| {
            (t0 + l).max(Instant::now() + Duration::from_millis(1))
        });
    add_plan_value(p, &mut lb, &b0, tol, eval_deadline);
    report(&mut lb, &mut ub, trials, true);
    Ok(Solution {
        lower: lb.value(&b0),
        upper: ub.value(&b0),
        policy: AlphaPolicy {
            n_states: p.n_states(),
            n_actions: p.n_actions(),
            vectors: lb.vectors,
            actions: lb.actions,
        },
        plan: lb.graph,
        plan_nodes: lb.nodes,
        time_s: t0.elapsed().as_secs_f64(),
        trials,
        converged,
    })
}

/// Adds the exact value of the plan behind V̲(b₀) as α-vectors: one for
/// its start node and one for every node it reaches.
///
/// The vector best at b₀ is a lower estimate of its plan's value: backups
/// continue with the vectors of their time, and a successor later
/// redirected to a dominating vector is worth more. The plan reachable
/// from its node is a finite-state controller; [`graph::evaluate`] gives its
/// value with a certificate (each returned vector is below the plan's
/// value from every state), so the result is still the value of an
/// executable policy — a valid, tighter V̲(b₀) that the plan's simulation
/// (`crate::simulate_plan`) estimates without bias. Evaluation stops at
/// `deadline`; the certificate shift then keeps it a bound.
///
/// Every node's value joins Γ, not only the start's: the certified values
/// satisfy `W_k ≤ R_{a_k} + γ T_{a_k} Σ_o O W_{σ_k(o)}`, so with all of
/// them in Γ, `V̲ = max Γ` keeps `V̲ ≤ H_greedy V̲` and the greedy α-vector
/// policy (what [`crate::simulate`] and a live controller run) earns at
/// least V̲(b₀). With the start's alone, V̲(b₀) counts the successors at
/// their evaluated values while Γ holds only their older, lower backed-up
/// vectors; the greedy policy then re-chooses at the successor beliefs
/// from those and can earn less than V̲(b₀) (seen on the 300-state
/// light-dark chains: 27 below on average over four solves).
fn add_plan_value(p: &Pomdp, lb: &mut LowerBound, b0: &SparseBelief, tol: f64, deadline: Instant) {
    let (k, _) = lb.best(b0);
    let start = lb.graph.resolve(lb.nodes[k]);
    let (order, action, next) = graph::reachable(&lb.graph, start);
    let vector_of: std::collections::HashMap<u32, usize> =
        lb.nodes.iter().enumerate().map(|(k, &n)| (n, k)).collect();
    let (lo, _) = p.reward_range();
    let floor = vec![lo / (1.0 - p.discount); p.n_states()];
    let init = order
        .iter()
        .map(|n| {
            vector_of
                .get(n)
                .map_or(floor.clone(), |&k| lb.vectors[k].clone())
        })
        .collect();
    let values = graph::evaluate(p, &action, &next, init, tol, Some(deadline));
    if values.iter().flatten().all(|x| x.is_finite()) {
        // The certificate holds for this controller as it is now. Adding
        // a node's value redirects the nodes of the vectors it dominates
        // to that node; one inside the plan, whose evaluated value can
        // exceed its vector, would change the plan under its certificate,
        // so those keep their successors (their vectors still leave Γ).
        // A node whose value is dominated (an evaluation cut short by the
        // deadline leaves a large certificate shift) keeps its plan too;
        // the dominating vector in Γ is at least its value. The start
        // goes first, so V̲(b₀) is set even if a later node's value
        // replaces vectors.
        let inside: HashSet<u32> = order.iter().copied().collect();
        for ((alpha, &a), &node) in values.into_iter().zip(&action).zip(&order) {
            lb.add_protecting(alpha, a, node, &inside);
        }
    }
}

/// A hash of the belief's support and masses (bit for bit).
fn belief_hash(b: &SparseBelief) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    b.idx.hash(&mut h);
    for v in &b.val {
        v.to_bits().hash(&mut h);
    }
    h.finish()
}

fn successors(p: &Pomdp, upd: &mut Updater, b: &SparseBelief) -> Vec<Vec<Branch>> {
    (0..p.n_actions())
        .map(|a| upd.successors(p, b, a))
        .collect()
}

fn argmax(v: &[f64]) -> (usize, f64) {
    v.iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |best, (i, &x)| {
            if x > best.1 {
                (i, x)
            } else {
                best
            }
        })
}
