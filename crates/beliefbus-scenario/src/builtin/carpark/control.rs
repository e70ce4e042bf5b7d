//! Backend `pure-pursuit`: steer the Ute along the data set's true path
//! (the loop the recorded drive took, along which the landmarks lie) from
//! the filter's belief, by pure pursuit (Coulter 1992) on the rear axle:
//!
//! ```text
//! rear axle  c = p − (a cos β − b sin β, a sin β + b cos β)      (p: the laser point)
//! goal       g = the rear axle of the first path pose at least ℓ from p,
//!            ahead of the nearest one (path poses are laser poses too)
//! η = atan2(g − c) − β,   α = atan(2 L sin η / ℓ),   clamped to ±max_steering
//! ```
//!
//! The wheel speed stays the recorded one (the plant applies it). The
//! nearest path point is searched in a window ahead of the previous one,
//! so a path that passes the same place twice is followed in order. The
//! reported cost is the distance from the laser point to that nearest
//! path point (the cross-track error). Allocation-free.

use super::{CarparkSystem, STATE};
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use beliefbus_localization::carpark::CarPark;
use beliefbus_localization::geometry::laser_point;
use std::sync::Arc;

/// Path points searched behind and ahead of the previous nearest one.
const BEHIND: usize = 40;
const AHEAD: usize = 400;

/// The nearest path point to (x, y) in a window around `from`.
pub fn nearest(cp: &CarPark, from: usize, x: f64, y: f64) -> (usize, f64) {
    let lo = from.saturating_sub(BEHIND);
    let hi = (from + AHEAD).min(cp.truth.len() - 1);
    let mut best = (from.min(hi), f64::INFINITY);
    for (i, p) in cp.truth[lo..=hi].iter().enumerate() {
        let d2 = (p[0] - x).powi(2) + (p[1] - y).powi(2);
        if d2 < best.1 {
            best = (lo + i, d2);
        }
    }
    (best.0, best.1.sqrt())
}

/// The controller.
#[derive(Debug)]
pub struct PurePursuit {
    cp: Arc<CarPark>,
    lookahead: f64,
    max_steering: f64,
    /// The nearest path point at the last step.
    index: usize,
}

impl PurePursuit {
    /// From `[carpark.control]`.
    pub fn new(sys: &CarparkSystem) -> Result<Self, String> {
        let c = &sys.params.control;
        Ok(Self {
            cp: sys.carpark.clone(),
            lookahead: c.lookahead_m,
            max_steering: c.max_steering,
            index: 0,
        })
    }
}

impl Controller for PurePursuit {
    fn name(&self) -> &'static str {
        super::PURE_PURSUIT
    }
    fn control_dim(&self) -> usize {
        1
    }
    /// The path is the goal.
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {
        self.index = 0;
    }
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        // A SLAM belief carries its map's size after the pose.
        if belief.dim < STATE {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: STATE,
            });
        }
        if !belief.is_finite() {
            return Err(ControlError::NonFinite);
        }
        let ute = &self.cp.ute;
        let (px, py, beta) = (belief.mean[0], belief.mean[1], belief.mean[2]);
        let (i, cross) = nearest(&self.cp, self.index, px, py);
        self.index = i;
        // The rear axle: the laser point moved back by the offset.
        let off = laser_point(0.0, 0.0, beta, ute.a, ute.b);
        let (cx, cy) = (px - off[0], py - off[1]);
        let path = &self.cp.truth;
        let mut g = path.len() - 1;
        for (k, p) in path.iter().enumerate().skip(i) {
            // Path points are laser points too: compare like with like.
            if (p[0] - px).hypot(p[1] - py) >= self.lookahead {
                g = k;
                break;
            }
        }
        let goal = path[g];
        let goff = laser_point(0.0, 0.0, goal[2], ute.a, ute.b);
        let (gx, gy) = (goal[0] - goff[0], goal[1] - goff[1]);
        let ld = (gx - cx).hypot(gy - cy).max(1e-6);
        let eta = (gy - cy).atan2(gx - cx) - beta;
        let alpha = (2.0 * ute.l * eta.sin() / ld).atan();
        if !alpha.is_finite() {
            return Err(ControlError::Numerical("pure pursuit steering"));
        }
        u[0] = alpha.clamp(-self.max_steering, self.max_steering);
        Ok(ControlInfo {
            cost: cross,
            samples: 0,
            ess: 0.0,
        })
    }
}
