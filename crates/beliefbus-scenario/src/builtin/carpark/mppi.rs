//! Backend `path-mppi`: path following by model-predictive path-integral
//! control (paper 003's path-integral control, sampled as MPPI, Williams et
//! al. 2017; [`beliefbus_core::control::mppi`]) on the Ute's kinematics,
//! an alternative to [`super::control::PurePursuit`].
//!
//! Rollouts run on z = (x, y, β, v_c): the laser pose and the rear-axle
//! speed, held over the horizon (the plant applies the recorded wheel
//! speed; the controller takes the data set's speed at the nearest path
//! point). The control is the steering α:
//!
//! ```text
//! ż = (v (cos β − tan α/L (a sin β + b cos β)), v (sin β + tan α/L (a cos β − b sin β)), v tan α / L, 0)   (E10)
//! q(z) = w d(z, P)²,   Φ(z) = w_T d(z, P)²
//! ```
//!
//! with d the distance of the laser point to P, the path's polyline from
//! just behind the nearest path point to beyond the horizon's reach
//! ([`PATH_POINTS`] points). MPPI's control cost r α², noise and limits
//! ±`max_steering` come from `[carpark.control]`. The reported cost is
//! the cross-track distance to the nearest path point (as pure pursuit's).
//! Allocation-free after construction.

use super::control::nearest;
use super::{CarparkSystem, STATE};
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::mppi::{Mppi, MppiConfig};
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use beliefbus_core::model::path_cost::PathCost;
use beliefbus_core::model::{Bounds, Dims, SdeModel};
use beliefbus_localization::carpark::CarPark;
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::vehicle::{Control, Ute};
use std::sync::Arc;

/// Points of the local path handed to the cost.
pub const PATH_POINTS: usize = 24;
/// Rollout state: pose and speed.
const Z: usize = 4;

/// The Ute's kinematics with the speed as a held state.
#[derive(Clone, Debug)]
pub struct CarModel {
    ute: Ute,
    bounds: Bounds,
}

impl CarModel {
    pub fn new(ute: Ute) -> Self {
        let big = 1e7;
        Self {
            ute,
            bounds: Bounds::new_box(&[-big, -big, -big, -100.0], &[big, big, big, 100.0])
                .expect("a non-empty box"),
        }
    }
}

impl SdeModel for CarModel {
    fn name(&self) -> &str {
        "carpark-car"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: Z,
            noise: 1,
            obs: 1,
            control: 1,
        }
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        let d = self.ute.drift(
            &Pose::new(x[0], x[1], x[2]),
            Control {
                v: x[3],
                alpha: u[0],
            },
        );
        f[0] = d[0];
        f[1] = d[1];
        f[2] = d[2];
        f[3] = 0.0;
    }
    /// Deterministic rollouts: the sampling is in the control.
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f.fill(0.0);
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std.fill(1.0);
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

/// w d² to a polyline set by [`PathCost::set_goal`] (x₀, y₀, x₁, y₁, …).
#[derive(Clone, Debug)]
pub struct PolylineCost {
    pts: [[f64; 2]; PATH_POINTS],
    n: usize,
    weight: f64,
    terminal_weight: f64,
}

impl PolylineCost {
    pub fn new(weight: f64, terminal_weight: f64) -> Self {
        Self {
            pts: [[0.0; 2]; PATH_POINTS],
            n: 0,
            weight,
            terminal_weight,
        }
    }

    /// Squared distance from (x, y) to the polyline (to its one point, or
    /// 0 without points).
    pub fn dist2(&self, x: f64, y: f64) -> f64 {
        match self.n {
            0 => 0.0,
            1 => (x - self.pts[0][0]).powi(2) + (y - self.pts[0][1]).powi(2),
            n => {
                let mut best = f64::INFINITY;
                for w in self.pts[..n].windows(2) {
                    let (ax, ay) = (w[0][0], w[0][1]);
                    let (dx, dy) = (w[1][0] - ax, w[1][1] - ay);
                    let l2 = dx * dx + dy * dy;
                    let s = if l2 > 0.0 {
                        (((x - ax) * dx + (y - ay) * dy) / l2).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    let d2 = (x - ax - s * dx).powi(2) + (y - ay - s * dy).powi(2);
                    best = best.min(d2);
                }
                best
            }
        }
    }
}

impl PathCost for PolylineCost {
    fn running(&self, x: &[f64]) -> f64 {
        self.weight * self.dist2(x[0], x[1])
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        self.terminal_weight * self.dist2(x[0], x[1])
    }
    fn set_goal(&mut self, goal: &[f64]) {
        self.n = (goal.len() / 2).min(PATH_POINTS);
        for (p, g) in self.pts.iter_mut().zip(goal.chunks_exact(2)) {
            *p = [g[0], g[1]];
        }
    }
}

/// The controller.
pub struct MppiFollower {
    cp: Arc<CarPark>,
    mppi: Mppi<CarModel, PolylineCost>,
    /// Path indices between the local path's points.
    stride: usize,
    index: usize,
    goal: [f64; 2 * PATH_POINTS],
}

impl MppiFollower {
    /// From `[carpark.control]`; the noise stream from `seed`.
    pub fn new(sys: &CarparkSystem, seed: u64) -> Result<Self, String> {
        let c = &sys.params.control;
        let cp = sys.carpark.clone();
        let cfg = MppiConfig {
            samples: c.mppi_samples,
            horizon_steps: c.mppi_horizon_steps,
            dt: c.mppi_dt,
            temperature: c.mppi_temperature,
            noise_std: vec![c.mppi_noise_std],
            u_min: vec![-c.max_steering],
            u_max: vec![c.max_steering],
            control_weight: c.mppi_control_weight,
            smoothing: c.mppi_horizon_steps >= 5,
            seed,
        };
        let cost = PolylineCost::new(1.0, c.mppi_horizon_steps as f64 * c.mppi_dt);
        let mppi = Mppi::new(CarModel::new(cp.ute), cost, &cfg).map_err(|e| {
            format!(
                "carpark.control.mppi_{}",
                e.to_string().trim_start_matches(' ')
            )
        })?;
        // The local path covers the horizon at the data set's top speed
        // (about 7 m/s) with the points spread evenly; path points are one
        // odometry step apart, about 0.1 m at a typical 4 m/s.
        let reach_m = 7.0 * c.mppi_horizon_steps as f64 * c.mppi_dt + 4.0;
        let metres_per_index = 4.0 * cp.ute.dt;
        let stride = ((reach_m / metres_per_index) / PATH_POINTS as f64)
            .ceil()
            .max(1.0) as usize;
        Ok(Self {
            cp,
            mppi,
            stride,
            index: 0,
            goal: [0.0; 2 * PATH_POINTS],
        })
    }
}

impl Controller for MppiFollower {
    fn name(&self) -> &'static str {
        super::MPPI
    }
    fn control_dim(&self) -> usize {
        1
    }
    /// The path is the goal.
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {
        self.index = 0;
        self.mppi.reset();
    }
    /// The next rollouts' noise, off the critical path.
    fn prepare(&mut self) {
        self.mppi.prepare();
    }
    fn compute(
        &mut self,
        t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        if belief.dim < STATE {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: STATE,
            });
        }
        if !belief.is_finite() {
            return Err(ControlError::NonFinite);
        }
        let (px, py, beta) = (belief.mean[0], belief.mean[1], belief.mean[2]);
        let (i, cross) = nearest(&self.cp, self.index, px, py);
        self.index = i;
        let path = &self.cp.truth;
        let last = path.len() - 1;
        let from = i.saturating_sub(self.stride);
        for k in 0..PATH_POINTS {
            let p = path[(from + k * self.stride).min(last)];
            self.goal[2 * k] = p[0];
            self.goal[2 * k + 1] = p[1];
        }
        self.mppi.set_goal(&self.goal);
        let v = self.cp.controls[i.min(self.cp.controls.len() - 1)].v;
        let mut z = Gaussian::zeros(Z);
        z.mean[..Z].copy_from_slice(&[px, py, beta, v]);
        for k in 0..Z {
            z.set_cov(k, k, 0.0);
        }
        let info = self.mppi.compute(t, &z, u)?;
        Ok(ControlInfo {
            cost: cross,
            samples: info.samples,
            ess: info.ess,
        })
    }
}
