//! The inventory-control benchmark of paper §VI.
//!
//! ```text
//! x_{k+1} = max(x_k + a_k Q − u_k, 0)          zero lead time, lost sales
//! y_k     = x_k + v_k,  v_k ~ N(0, σ²)
//! g_k     = h·max(x_k + a_k Q − u_k, 0) + s·max(u_k − x_k − a_k Q, 0)
//! ```
//!
//! a_k ∈ {0, 1}, u_k ~ Exponential with mean 5 (the paper's "exp(5)"; only
//! mean 5 puts the full-observation optimum near its L* = 7.7), h = 1,
//! s = 10, Q = 10, x_0 = 5.

pub mod exact;
pub mod policies;
pub mod sim;

use crate::model::{FilterModel, Pomdp};
use crate::policy::PolicyKey;
use crate::rng::SimRng;
use crate::ProjectionError;
use rand::RngExt;
use rand_distr::{Exp1, StandardNormal};

/// The inventory POMDP.
#[derive(Clone, Debug, PartialEq)]
pub struct Inventory {
    /// Holding cost per unit per period.
    pub h: f64,
    /// Shortage penalty per unit of lost sales.
    pub s: f64,
    /// Fixed order quantity.
    pub q: f64,
    /// Mean of the exponential demand.
    pub demand_mean: f64,
    /// Observation noise standard deviation.
    pub sigma: f64,
    /// Known initial inventory.
    pub x0: f64,
    controls: [[f64; 1]; 2],
}

impl Inventory {
    /// A model; every parameter finite, costs and noise positive.
    pub fn new(
        h: f64,
        s: f64,
        q: f64,
        demand_mean: f64,
        sigma: f64,
        x0: f64,
    ) -> Result<Self, ProjectionError> {
        let ok = [h, s, q, demand_mean, sigma]
            .iter()
            .all(|v| v.is_finite() && *v > 0.0)
            && x0.is_finite()
            && x0 >= 0.0;
        if !ok {
            return Err(ProjectionError::invalid(
                "inventory parameters",
                format!("h={h} s={s} Q={q} demand_mean={demand_mean} sigma={sigma} x0={x0}: need positive finite h, s, Q, demand mean, sigma and x0 >= 0"),
            ));
        }
        Ok(Self {
            h,
            s,
            q,
            demand_mean,
            sigma,
            x0,
            controls: [[0.0], [q]],
        })
    }

    /// The paper's parameters at observation noise σ.
    pub fn paper(sigma: f64) -> Result<Self, ProjectionError> {
        Self::new(1.0, 10.0, 10.0, 5.0, sigma, 5.0)
    }

    /// The same model at another noise level.
    pub fn with_sigma(&self, sigma: f64) -> Result<Self, ProjectionError> {
        Self::new(self.h, self.s, self.q, self.demand_mean, sigma, self.x0)
    }

    /// Inventory after ordering (action a ∈ {0,1}).
    #[inline]
    pub fn stocked(&self, x: f64, a: usize) -> f64 {
        x + a as f64 * self.q
    }

    /// x_{k+1} for demand u.
    #[inline]
    pub fn next_state(&self, x: f64, a: usize, demand: f64) -> f64 {
        (self.stocked(x, a) - demand).max(0.0)
    }

    /// g_k for demand u.
    #[inline]
    pub fn cost(&self, x: f64, a: usize, demand: f64) -> f64 {
        let z = self.stocked(x, a) - demand;
        if z >= 0.0 {
            self.h * z
        } else {
            -self.s * z
        }
    }

    /// E_u[g(x, a, u)] in closed form for exponential demand with mean β and
    /// z = x + aQ: h(z − β + βe^{−z/β}) + sβe^{−z/β} for z ≥ 0, s(β − z)
    /// for z < 0 (every unit short).
    pub fn expected_cost(&self, x: f64, a: usize) -> f64 {
        let (z, b) = (self.stocked(x, a), self.demand_mean);
        if z <= 0.0 {
            self.s * (b - z)
        } else {
            let tail = b * (-z / b).exp();
            self.h * (z - b + tail) + self.s * tail
        }
    }

    /// One demand draw.
    #[inline]
    pub fn sample_demand(&self, rng: &mut SimRng) -> f64 {
        let e: f64 = rng.sample(Exp1);
        self.demand_mean * e
    }

    /// The model's part of a policy key.
    pub fn key(&self) -> PolicyKey {
        PolicyKey::new()
            .text("model", "inventory")
            .num("h", self.h)
            .num("s", self.s)
            .num("Q", self.q)
            .num("demand_mean", self.demand_mean)
            .num("sigma", self.sigma)
    }
}

impl FilterModel for Inventory {
    fn state_dim(&self) -> usize {
        1
    }

    fn obs_dim(&self) -> usize {
        1
    }

    fn sample_transition(&self, x: &mut [f64], u: &[f64], rng: &mut SimRng) {
        let d = self.sample_demand(rng);
        x[0] = (x[0] + u[0] - d).max(0.0);
    }

    #[inline]
    fn obs_log_likelihood(&self, x: &[f64], y: &[f64]) -> f64 {
        let r = (y[0] - x[0]) / self.sigma;
        -0.5 * r * r
    }

    /// Inventory is never negative: a Gaussian belief's mass below zero is
    /// an empty store.
    fn constrain(&self, x: &mut [f64]) {
        x[0] = x[0].max(0.0);
    }
}

impl Pomdp for Inventory {
    fn num_actions(&self) -> usize {
        2
    }

    fn action_control(&self, a: usize) -> &[f64] {
        &self.controls[a]
    }

    fn sample_step(&self, x: &mut [f64], a: usize, rng: &mut SimRng) -> f64 {
        let d = self.sample_demand(rng);
        let g = self.cost(x[0], a, d);
        x[0] = self.next_state(x[0], a, d);
        g
    }

    fn sample_observation(&self, x: &[f64], y: &mut [f64], rng: &mut SimRng) {
        let v: f64 = rng.sample(StandardNormal);
        y[0] = x[0] + self.sigma * v;
    }
}
