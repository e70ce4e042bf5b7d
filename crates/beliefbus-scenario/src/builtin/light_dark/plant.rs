//! The true agent behind the plant stage: one decision period h per sensor
//! sample ([`Plant::step`]) under the control in force.
//!
//! Per step: a declaration (control d = 1) ends the episode with ±R by
//! whether x is in the goal, and the next episode starts at a draw from b₀;
//! `max_steps` moves without one end it too (a timeout, reward 0);
//! otherwise the agent moves with velocity v for h at cost v²h:
//! - `chain`: the next chain state is drawn from the POMDP's row
//!   T(·|z, a) of the action a whose control is v (the model the policy
//!   was solved for; b₀ uniform over the states);
//! - `sde`: Euler–Maruyama on dx = v dt + σ dw over h in steps of at most
//!   `plant.integration_dt`, reflected at ±2 (b₀ uniform on [−2, 2]).
//!
//! Then y = x + G(x) v with v ~ N(0, 1). The first sample starts the first
//! episode.

use super::encoding::{
    EVENT_GOAL, EVENT_MISS, EVENT_NONE, EVENT_TIMEOUT, STATE, U_DECLARE, U_VELOCITY,
};
use super::model::{LightObs, HALF};
use super::{LightDarkParams, LightDarkSystem, PlantKind};
use crate::rng::SimRng;
use crate::Plant;
use beliefbus_pomdp::chain_pomdp::ChainPomdp;
use rand::RngExt;
use rand_distr::StandardNormal;
use std::sync::Arc;

/// The simulated agent.
#[derive(Debug)]
pub struct LightDarkPlant {
    params: LightDarkParams,
    kind: PlantKind,
    cp: Arc<ChainPomdp>,
    obs: LightObs,
    sys: LightDarkSystem,
    /// (x, r, e) of [`super::encoding`].
    x: [f64; STATE],
    /// The chain state (plant `chain`).
    z: usize,
    u: [f64; super::encoding::CONTROL],
    applied: f64,
    new_episode: bool,
    moves: u64,
    started: bool,
    max_dt: f64,
    rng: SimRng,
}

impl LightDarkPlant {
    pub fn new(sys: &LightDarkSystem, seed: u64, max_dt: f64) -> Self {
        Self {
            params: sys.params.clone(),
            kind: sys.plant_kind,
            cp: sys.pomdp.clone(),
            obs: sys.params.obs(),
            sys: sys.clone(),
            x: [0.0; STATE],
            z: 0,
            u: [0.0; super::encoding::CONTROL],
            applied: 0.0,
            new_episode: false,
            moves: 0,
            started: false,
            max_dt: if max_dt.is_finite() && max_dt > 0.0 {
                max_dt
            } else {
                1e-3
            },
            rng: crate::rng::stream(seed, 0x4c44),
        }
    }

    /// A draw from b₀.
    fn start_episode(&mut self) {
        match self.kind {
            PlantKind::Chain => {
                let n = self.cp.n_chain();
                self.z = self.rng.random_range(0..n);
                self.x[0] = self.cp.state(self.z)[0];
            }
            PlantKind::Sde => self.x[0] = self.rng.random_range(-HALF..HALF),
        }
        self.moves = 0;
        self.new_episode = true;
    }

    /// One period with velocity `v`; returns its reward.
    fn advance_period(&mut self, v: f64) -> f64 {
        let h = self.cp.period;
        match self.kind {
            PlantKind::Chain => {
                let a = self.sys.nearest_action(v);
                let (cols, vals) = self.cp.pomdp.trans[a].row(self.z);
                let r: f64 = self.rng.random();
                let mut acc = 0.0;
                let mut next = cols.last().map_or(self.z, |&c| c as usize);
                for (&c, &p) in cols.iter().zip(vals) {
                    acc += p;
                    if r < acc {
                        next = c as usize;
                        break;
                    }
                }
                self.z = next;
                self.x[0] = self.cp.state(next)[0];
            }
            PlantKind::Sde => {
                let steps = (h / self.max_dt).ceil().max(1.0);
                let dt = h / steps;
                let mut x = self.x[0];
                for _ in 0..steps as usize {
                    let w: f64 = self.rng.sample(StandardNormal);
                    x += v * dt + self.params.noise * dt.sqrt() * w;
                    // Reflect at the walls.
                    if x > HALF {
                        x = 2.0 * HALF - x;
                    }
                    if x < -HALF {
                        x = -2.0 * HALF - x;
                    }
                    x = x.clamp(-HALF, HALF);
                }
                self.x[0] = x;
            }
        }
        self.applied = v;
        self.moves += 1;
        -v * v * h
    }
}

impl Plant for LightDarkPlant {
    fn state(&self) -> &[f64] {
        &self.x
    }
    fn control(&self) -> &[f64] {
        &self.u
    }
    fn set_control(&mut self, u: &[f64]) {
        let n = u.len().min(self.u.len());
        self.u[..n].copy_from_slice(&u[..n]);
    }
    /// Discrete time: nothing moves between samples.
    fn advance(&mut self, _dt: f64) {}
    fn step(&mut self) {
        self.new_episode = false;
        self.applied = 0.0;
        if !self.started {
            self.started = true;
            self.x[1] = 0.0;
            self.x[2] = EVENT_NONE;
            self.start_episode();
            return;
        }
        let (reward, event) = if self.u[U_DECLARE] > 0.5 {
            if self.params.in_goal(self.x[0]) {
                (self.params.reward, EVENT_GOAL)
            } else {
                (-self.params.reward, EVENT_MISS)
            }
        } else if self.moves >= self.params.max_steps {
            (0.0, EVENT_TIMEOUT)
        } else {
            let v = self.u[U_VELOCITY];
            (self.advance_period(v), EVENT_NONE)
        };
        self.x[1] = reward;
        self.x[2] = event;
        if event != EVENT_NONE {
            self.start_episode();
        }
    }
    fn measure(&mut self, y: &mut [f64]) {
        let v: f64 = self.rng.sample(StandardNormal);
        y[0] = self.x[0] + self.obs.std(self.x[0]) * v;
        if y.len() >= 3 {
            y[1] = self.applied;
            y[2] = if self.new_episode { 1.0 } else { 0.0 };
        }
    }
}
