//! The true inventory behind the plant stage: one period per sensor sample
//! ([`Plant::step`]) under the order in force, exponential demand and
//! Gaussian count noise.
//!
//! The random numbers are the `inventory-average` experiment's: its
//! environment stream of run 0 at seed `run.seed`, drawn in its order (per
//! period the demand, then the standardised count noise). A live run of
//! seed S therefore meets the demands and noises of the first periods of
//! `beliefbus experiment inventory-average --seed S`: the two differ only
//! by the filter's own draws and by the pipeline's timing.
//!
//! The first sample measures x_0 (no period has passed); each later one
//! first runs the period x_{k+1} = max(x_k + u_k − d_k, 0) with u_k the
//! order in force, recording d_k and its cost g_k in the state, then
//! measures (x_{k+1} + v, u_k).

use super::{InventorySystem, STATE};
use crate::rng::SimRng;
use crate::Plant;
use beliefbus_projection::inventory::sim::env_rng;
use beliefbus_projection::inventory::Inventory;
use rand::RngExt;
use rand_distr::StandardNormal;

/// The simulated store.
#[derive(Debug)]
pub struct InventoryPlant {
    model: Inventory,
    /// (x_k, d_{k−1}, g_{k−1}).
    x: [f64; STATE],
    u: [f64; 1],
    u_applied: f64,
    started: bool,
    /// The demand of the period that starts at the last measurement.
    demand: f64,
    rng: SimRng,
}

impl InventoryPlant {
    /// Start at `x0` (inventory, last demand, last cost).
    pub fn new(sys: &InventorySystem, x0: &[f64], seed: u64) -> Result<Self, String> {
        if x0.len() != STATE || x0.iter().any(|v| !v.is_finite()) || x0[0] < 0.0 {
            return Err(format!(
                "inventory plant: the initial state needs {STATE} finite entries, inventory >= 0"
            ));
        }
        let mut x = [0.0; STATE];
        x.copy_from_slice(x0);
        Ok(Self {
            model: sys.model.clone(),
            x,
            u: [0.0],
            u_applied: 0.0,
            started: false,
            demand: 0.0,
            rng: env_rng(seed, 0),
        })
    }
}

impl Plant for InventoryPlant {
    fn state(&self) -> &[f64] {
        &self.x
    }
    fn control(&self) -> &[f64] {
        &self.u
    }
    /// The order in force: anything above Q/2 orders Q, anything else
    /// nothing (the action set is {0, Q}).
    fn set_control(&mut self, u: &[f64]) {
        if let Some(&v) = u.first() {
            self.u[0] = if v > 0.5 * self.model.q {
                self.model.q
            } else {
                0.0
            };
        }
    }
    /// Discrete time: nothing moves between samples.
    fn advance(&mut self, _dt: f64) {}
    fn step(&mut self) {
        if !self.started {
            self.started = true;
            return;
        }
        let a = usize::from(self.u[0] > 0.0);
        let d = self.demand;
        self.x[2] = self.model.cost(self.x[0], a, d);
        self.x[1] = d;
        self.x[0] = self.model.next_state(self.x[0], a, d);
        self.u_applied = self.u[0];
    }
    fn measure(&mut self, y: &mut [f64]) {
        self.demand = self.model.sample_demand(&mut self.rng);
        let v: f64 = self.rng.sample(StandardNormal);
        y[0] = self.x[0] + self.model.sigma * v;
        if y.len() > 1 {
            y[1] = self.u_applied;
        }
    }
}
