//! The true change-point ARX system behind the plant stage: one step of
//! (13) per sensor sample ([`Plant::step`]), θ jumping with probability ρ
//! to a fresh N(μ, V) draw (by rejection inside |a₁| + |a₂| < 1 when
//! `stable_ar`), ε_t ~ N(0, 1) from the plant's own seeded stream.
//!
//! Step t uses the control in force at the sample as u_{t−1}:
//! φ_t = (−y_{t−1}, −y_{t−2}, u_{t−1}), y_t = θ_tᵀφ_t + ε_t. The
//! measurement is (y_t, u_{t−1}). Started from a state (a restart resumes
//! from the last truth) it continues with those θ and lags; the input
//! before it is taken as 0.

use super::{ArxSystem, RUN_LENGTH, STATE, T0};
use crate::rng::SimRng;
use crate::{Plant, PLANT_STREAM};
use beliefbus_changepoint::arx::linalg::{cholesky, dot, Matrix, Vector};
use beliefbus_changepoint::arx::Regressor;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

/// The simulated system.
#[derive(Debug)]
pub struct ArxLivePlant {
    theta: Vector<3>,
    mu: Vector<3>,
    chol: Matrix<3>,
    rho: f64,
    stable: bool,
    reg: Regressor<3>,
    /// (θ, y_t, y_{t−1}, r_t in s).
    x: [f64; STATE],
    /// Control in force; the input applied at the last step.
    u: [f64; 1],
    u_applied: f64,
    run_steps: u64,
    t: u64,
    dt: f64,
    rng: SimRng,
}

impl ArxLivePlant {
    /// Start at `x0` (θ, y, y_prev, r).
    pub fn new(sys: &ArxSystem, x0: &[f64], seed: u64) -> Result<Self, String> {
        if x0.len() != STATE || x0.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "arx plant: the initial state needs {STATE} finite entries"
            ));
        }
        let prior = sys.theta_prior();
        let chol = cholesky(&prior.v).ok_or("arx plant: V is not positive definite")?;
        let mut reg = Regressor::new(2).map_err(|e| e.to_string())?;
        // φ after this push is (−y_{t−1}, 0, 0); the first step pushes
        // (y_t, u) on top of it.
        reg.push(x0[4], 0.0);
        let mut x = [0.0; STATE];
        x.copy_from_slice(x0);
        Ok(Self {
            theta: [x0[0], x0[1], x0[2]],
            mu: prior.mu,
            chol,
            rho: sys.params.rho,
            stable: sys.params.stable_ar,
            reg,
            x,
            u: [0.0],
            u_applied: 0.0,
            run_steps: (x0[RUN_LENGTH] / sys.sample_dt).round().max(0.0) as u64,
            t: 0,
            dt: sys.sample_dt,
            rng: crate::rng::stream(seed, PLANT_STREAM),
        })
    }

    /// A draw from N(μ, V), restricted to the AR stability region when
    /// asked.
    fn draw(&mut self) -> Vector<3> {
        loop {
            let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut self.rng));
            let mut th = self.mu;
            for i in 0..3 {
                for j in 0..=i {
                    th[i] += self.chol[i][j] * z[j];
                }
            }
            if !self.stable || th[0].abs() + th[1].abs() < 1.0 {
                return th;
            }
        }
    }

    /// Steps taken.
    pub fn t(&self) -> u64 {
        self.t
    }
}

impl Plant for ArxLivePlant {
    fn state(&self) -> &[f64] {
        &self.x
    }
    fn control(&self) -> &[f64] {
        &self.u
    }
    fn set_control(&mut self, u: &[f64]) {
        if let Some(&v) = u.first() {
            self.u[0] = v;
        }
    }
    /// Discrete time: nothing moves between samples.
    fn advance(&mut self, _dt: f64) {}
    fn step(&mut self) {
        self.t += 1;
        self.run_steps += 1;
        if self.t == 1 && self.x[3] == 0.0 && self.x[4] == 0.0 {
            // A fresh start: step 1 opens the first segment.
            self.run_steps = 0;
        }
        if self.t > T0 && self.rng.random::<f64>() < self.rho {
            self.theta = self.draw();
            self.run_steps = 0;
        }
        self.u_applied = self.u[0];
        self.reg.push(self.x[3], self.u_applied);
        let e: f64 = StandardNormal.sample(&mut self.rng);
        let y = dot(&self.theta, self.reg.phi()) + e;
        self.x[..3].copy_from_slice(&self.theta);
        self.x[4] = self.x[3];
        self.x[3] = y;
        self.x[RUN_LENGTH] = self.run_steps as f64 * self.dt;
    }
    /// (y_t, u_{t−1}): exact (ε is the model's noise, already in y_t).
    fn measure(&mut self, y: &mut [f64]) {
        y[0] = self.x[3];
        if y.len() > 1 {
            y[1] = self.u_applied;
        }
    }
}
