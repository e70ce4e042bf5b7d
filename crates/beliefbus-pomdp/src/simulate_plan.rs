//! Simulating the controller behind the lower bound.
//!
//! [`crate::simulate`] runs the greedy policy: at every step the action of
//! the α-vector that is best at the current belief. Its value lies between
//! the lower bound V̲(b₀) and V*(b₀), so on a problem whose bounds are still
//! apart (Hallway after 300 s: [1.003, 1.194]) the greedy policy's reward can
//! sit well above V̲(b₀) — the bound is then loose, not wrong.
//!
//! What certifies the bound itself is its own controller. Every α-vector
//! the solver keeps is the value of a plan ([`crate::solver::graph`]): an
//! action, then per observation the plan to continue with. Starting from
//! the plan of the vector that attains V̲(b₀) = max_k α_k·b₀ and following
//! its successors — no belief is tracked — the expected discounted reward
//! is that plan's value at b₀: exactly α_k·b₀ when no successor was
//! replaced, at least it when one was redirected to a vector dominating it
//! everywhere. A simulated mean clearly *below* V̲(b₀) therefore disproves
//! the bound; one that agrees within its standard error confirms it.

use crate::model::Pomdp;
use crate::simulate::{horizon, sample, stream, SimulateError, SimulateOptions, SimulationResult};
use crate::solver::Solution;

/// The lower bound's controller run from b₀ ([module doc](self)).
#[derive(Clone, Debug, PartialEq)]
pub struct PlanSimulation {
    /// The mean discounted reward and its standard error.
    pub result: SimulationResult,
    /// The vector attaining V̲(b₀) and its value there.
    pub vector: usize,
    pub vector_value: f64,
}

/// Runs the plan of the vector best at b₀ ([module doc](self)).
pub fn simulate_plan(
    p: &Pomdp,
    sol: &Solution,
    opts: &SimulateOptions,
) -> Result<PlanSimulation, SimulateError> {
    sol.policy.check_fits(p.n_states(), p.n_actions())?;
    if opts.runs < 2 {
        return Err(SimulateError::Runs(opts.runs));
    }
    if !(p.discount < 1.0) {
        return Err(SimulateError::Discount(p.discount));
    }
    if !(opts.precision > 0.0) {
        return Err(SimulateError::Precision(opts.precision));
    }
    let (vector, vector_value) = sol.policy.best_dense(&p.start);
    let start = sol.plan.resolve(sol.plan_nodes[vector]);
    let h = horizon(p, opts.precision);
    let threads = opts.threads.clamp(1, opts.runs);
    let per = opts.runs.div_ceil(threads);
    let mut returns = vec![0.0; opts.runs];
    std::thread::scope(|scope| {
        for (t, chunk) in returns.chunks_mut(per).enumerate() {
            scope.spawn(move || {
                for (k, r) in chunk.iter_mut().enumerate() {
                    let mut rng = stream(opts.seed, (t * per + k) as u64);
                    let mut s = sample(
                        &mut rng,
                        p.start.iter().enumerate().map(|(i, &q)| (i as u32, q)),
                    );
                    let mut node = start;
                    let (mut ret, mut disc) = (0.0, 1.0);
                    for _ in 0..h {
                        let a = sol.plan.action(node);
                        ret += disc * p.reward[a][s as usize];
                        disc *= p.discount;
                        let (cols, vals) = p.trans[a].row(s as usize);
                        s = sample(&mut rng, cols.iter().copied().zip(vals.iter().copied()));
                        let (obs, probs) = p.obs[a].row(s as usize);
                        let o = sample(&mut rng, obs.iter().copied().zip(probs.iter().copied()));
                        node = sol.plan.next(node, o as usize);
                    }
                    *r = ret;
                }
            });
        }
    });
    let n = opts.runs as f64;
    let mean = returns.iter().sum::<f64>() / n;
    let var = returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Ok(PlanSimulation {
        result: SimulationResult {
            mean,
            std_err: (var / n).sqrt(),
            runs: opts.runs,
            horizon: h,
        },
        vector,
        vector_value,
    })
}
