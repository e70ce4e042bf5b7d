//! Closed-loop simulation of the inventory POMDP with common random numbers.
//!
//! Run r of seed S draws its demands u_k and standardised observation
//! noises ξ_k (v_k = σ ξ_k) from one stream and the filters' randomness from
//! another; both depend only on (S, r). Every policy and every σ therefore
//! meets the same demands, the same noise shapes and the same filter draws
//! (the paper: "common random variables among different policies and
//! different σ's"), and differences between policies are not sampling noise
//! of the environment.

use super::policies::{Controller, Observation};
use super::Inventory;
use crate::rng::{mix, stream, SimRng};
use crate::ProjectionError;
use rand::RngExt;
use rand_distr::StandardNormal;

const ROLE_ENV: u64 = 1;
const ROLE_FILTER: u64 = 2;

/// The exogenous randomness of one run: demands and standardised noises.
#[derive(Clone, Debug)]
pub struct Scenario {
    pub demand: Vec<f64>,
    pub xi: Vec<f64>,
}

impl Scenario {
    /// `steps` periods of run `run` of `seed`.
    pub fn new(model: &Inventory, seed: u64, run: u64, steps: usize) -> Self {
        let mut rng = env_rng(seed, run);
        let mut demand = Vec::with_capacity(steps);
        let mut xi = Vec::with_capacity(steps);
        for _ in 0..steps {
            demand.push(model.sample_demand(&mut rng));
            xi.push(rng.sample(StandardNormal));
        }
        Self { demand, xi }
    }

    /// Overwrite with run `run` of `seed` (same length), reusing buffers.
    pub fn refill(&mut self, model: &Inventory, seed: u64, run: u64) {
        let mut rng = env_rng(seed, run);
        for (d, x) in self.demand.iter_mut().zip(self.xi.iter_mut()) {
            *d = model.sample_demand(&mut rng);
            *x = rng.sample(StandardNormal);
        }
    }
}

/// The environment stream of run `run`: per period k, the demand u_k then
/// the standardised noise ξ_k. A live plant drawing from it meets the
/// demands and noises of the experiment's run.
pub fn env_rng(seed: u64, run: u64) -> SimRng {
    stream(seed, mix(&[ROLE_ENV, run]))
}

/// The filter stream of run `run` (shared by all policies and σ).
pub fn filter_rng(seed: u64, run: u64) -> SimRng {
    stream(seed, mix(&[ROLE_FILTER, run]))
}

/// Simulate `controller` over the scenario's periods from x_0; write the
/// cost of each period into `costs` (length = scenario length).
pub fn run_closed_loop<C: Controller + ?Sized>(
    model: &Inventory,
    controller: &mut C,
    scenario: &Scenario,
    rng: &mut SimRng,
    costs: &mut [f64],
) -> Result<(), ProjectionError> {
    ProjectionError::check_len("cost buffer", scenario.demand.len(), costs.len())?;
    controller.reset(model, rng)?;
    let mut x = model.x0;
    let mut prev = None;
    for (k, c) in costs.iter_mut().enumerate() {
        let obs = Observation {
            y: x + model.sigma * scenario.xi[k],
            x_true: x,
        };
        let a = controller.act(model, obs, prev, rng)?;
        *c = model.cost(x, a, scenario.demand[k]);
        x = model.next_state(x, a, scenario.demand[k]);
        prev = Some(a);
    }
    Ok(())
}

/// Σ_k γ^k c_k.
pub fn discounted_sum(costs: &[f64], gamma: f64) -> f64 {
    costs.iter().rev().fold(0.0, |acc, &c| c + gamma * acc)
}

/// Mean and standard error of `v` (sample standard deviation / √n).
pub fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (m, f64::NAN);
    }
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Mean of one long run and its batch-means standard error (`batches`
/// contiguous batches; correlation within a batch is absorbed when the
/// batch is much longer than the chain's mixing time).
pub fn batch_means(costs: &[f64], batches: usize) -> (f64, f64) {
    let b = batches.clamp(1, costs.len().max(1));
    let len = costs.len() / b;
    if len == 0 {
        return mean_se(costs);
    }
    let means: Vec<f64> = (0..b)
        .map(|i| costs[i * len..(i + 1) * len].iter().sum::<f64>() / len as f64)
        .collect();
    let (_, se) = mean_se(&means);
    (costs.iter().sum::<f64>() / costs.len() as f64, se)
}
