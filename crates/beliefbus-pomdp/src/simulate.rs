//! Monte-Carlo evaluation of an α-vector policy on its model.
//!
//! One run: draw s₀ ~ b₀; at each step act with the policy's action at the
//! current belief, collect `γ^t R(s_t,a_t)`, draw `s_{t+1} ~ T(·|s_t,a_t)`
//! and `o ~ O(·|s_{t+1},a_t)`, and update the belief by Bayes' rule. Runs
//! stop at the horizon H where the discarded tail `γ^H max|R|/(1−γ)` is
//! below the requested precision. The estimate is the mean over runs with
//! its standard error `sd/√N`. Run `i` uses random stream `(seed, i)`, so the
//! result does not depend on how the runs are split over threads.

use crate::belief::{SparseBelief, Updater};
use crate::model::Pomdp;
use crate::policy::{AlphaPolicy, PolicyError};
use rand::{RngExt, SeedableRng};
use thiserror::Error;

/// The random generator of each run.
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;

/// Settings of [`simulate`].
#[derive(Clone, Debug)]
pub struct SimulateOptions {
    pub runs: usize,
    pub seed: u64,
    /// Truncation error allowed on each run's discounted return.
    pub precision: f64,
    pub threads: usize,
}

impl Default for SimulateOptions {
    fn default() -> Self {
        SimulateOptions {
            runs: 1000,
            seed: 0,
            precision: 1e-3,
            threads: 2,
        }
    }
}

/// Mean discounted reward over the runs and its standard error.
#[derive(Clone, Debug, PartialEq)]
pub struct SimulationResult {
    pub mean: f64,
    pub std_err: f64,
    pub runs: usize,
    pub horizon: usize,
}

#[derive(Debug, Error)]
pub enum SimulateError {
    #[error(transparent)]
    Policy(#[from] PolicyError),
    #[error("need at least 2 runs for a standard error, got {0}")]
    Runs(usize),
    #[error("discount {0} must be below 1 (the horizon is derived from it)")]
    Discount(f64),
    #[error("precision {0} must be positive")]
    Precision(f64),
}

/// Steps after which `γ^H · max|R|/(1−γ) ≤ precision`.
pub fn horizon(p: &Pomdp, precision: f64) -> usize {
    let (lo, hi) = p.reward_range();
    let rmax = lo.abs().max(hi.abs()) / (1.0 - p.discount);
    if rmax <= precision || p.discount == 0.0 {
        return 1;
    }
    ((precision / rmax).ln() / p.discount.ln()).ceil() as usize
}

/// Estimates the policy's expected discounted reward from b₀.
pub fn simulate(
    p: &Pomdp,
    policy: &AlphaPolicy,
    opts: &SimulateOptions,
) -> Result<SimulationResult, SimulateError> {
    policy.check_fits(p.n_states(), p.n_actions())?;
    if opts.runs < 2 {
        return Err(SimulateError::Runs(opts.runs));
    }
    if !(p.discount < 1.0) {
        return Err(SimulateError::Discount(p.discount));
    }
    if !(opts.precision > 0.0) {
        return Err(SimulateError::Precision(opts.precision));
    }
    let h = horizon(p, opts.precision);
    let threads = opts.threads.clamp(1, opts.runs);
    let mut returns = vec![0.0; opts.runs];
    std::thread::scope(|scope| {
        for (t, chunk) in returns.chunks_mut(opts.runs.div_ceil(threads)).enumerate() {
            let first = t * opts.runs.div_ceil(threads);
            scope.spawn(move || {
                let mut runner = Runner::new(p);
                for (k, r) in chunk.iter_mut().enumerate() {
                    let mut rng = stream(opts.seed, (first + k) as u64);
                    *r = runner.run(p, policy, h, &mut rng);
                }
            });
        }
    });
    let n = opts.runs as f64;
    let mean = returns.iter().sum::<f64>() / n;
    let var = returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Ok(SimulationResult {
        mean,
        std_err: (var / n).sqrt(),
        runs: opts.runs,
        horizon: h,
    })
}

/// Generator for run `run` of a simulation seeded with `seed` (SplitMix64
/// mixing, so neighbouring runs get unrelated streams).
pub fn stream(seed: u64, run: u64) -> SimRng {
    SimRng::seed_from_u64(splitmix64(
        seed ^ splitmix64(run.wrapping_add(0x9E37_79B9_7F4A_7C15)),
    ))
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Buffers of one simulating thread.
struct Runner {
    upd: Updater,
    pred: SparseBelief,
}

impl Runner {
    fn new(p: &Pomdp) -> Self {
        Runner {
            upd: Updater::new(p),
            pred: SparseBelief::default(),
        }
    }

    fn run(&mut self, p: &Pomdp, policy: &AlphaPolicy, h: usize, rng: &mut SimRng) -> f64 {
        let mut s = sample(rng, p.start.iter().enumerate().map(|(i, &q)| (i as u32, q)));
        let mut b = SparseBelief::from_dense(&p.start);
        let mut ret = 0.0;
        let mut disc = 1.0;
        for _ in 0..h {
            let a = policy.actions[policy.best_sparse(&b).0];
            ret += disc * p.reward[a][s as usize];
            disc *= p.discount;
            let (cols, vals) = p.trans[a].row(s as usize);
            s = sample(rng, cols.iter().copied().zip(vals.iter().copied()));
            let (obs, probs) = p.obs[a].row(s as usize);
            let o = sample(rng, obs.iter().copied().zip(probs.iter().copied()));
            // b^{a,o}(s') ∝ O(o|s',a) b'_a(s')
            self.upd.predict(p, &b, a, &mut self.pred);
            b.idx.clear();
            b.val.clear();
            let mut z = 0.0;
            for (&s2, &q) in self.pred.idx.iter().zip(&self.pred.val) {
                let w = q * p.obs[a].get(s2 as usize, o as usize);
                if w > 0.0 {
                    b.idx.push(s2);
                    b.val.push(w);
                    z += w;
                }
            }
            if z > 0.0 {
                b.val.iter_mut().for_each(|v| *v /= z);
            } else {
                // Every state consistent with o underflowed: keep the
                // prediction rather than divide by zero.
                let total: f64 = self.pred.val.iter().sum();
                b.idx.clone_from(&self.pred.idx);
                b.val.clear();
                b.val.extend(self.pred.val.iter().map(|v| v / total));
            }
        }
        ret
    }
}

/// Draws an index from `(index, probability)` pairs summing to one (the
/// last index absorbs rounding).
pub(crate) fn sample(rng: &mut SimRng, items: impl Iterator<Item = (u32, f64)>) -> u32 {
    let u: f64 = rng.random();
    let mut acc = 0.0;
    let mut last = 0;
    for (i, q) in items {
        if q <= 0.0 {
            continue;
        }
        acc += q;
        last = i;
        if u < acc {
            return i;
        }
    }
    last
}
