//! Waypoint sequencing for the closed-loop scenarios: the active waypoint
//! advances when the believed position comes within `reach_radius` of it
//! (Euclidean distance over the scenario's position axes, one or more; a
//! set-point is a route of one waypoint with `cycle = false`).

use serde::{Deserialize, Serialize};

/// Settings of a waypoint route.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RouteConfig {
    /// Waypoints on the scenario's position axes (ship: (x, y)), visited
    /// in order.
    pub waypoints: Vec<Vec<f64>>,
    /// Distance at which a waypoint counts as reached.
    pub reach_radius: f64,
    /// Start again at the first waypoint after the last.
    #[serde(default = "default_true")]
    pub cycle: bool,
}

fn default_true() -> bool {
    true
}

/// Tracks progress along a route.
#[derive(Clone, Debug)]
pub struct WaypointTracker {
    cfg: RouteConfig,
    active: usize,
    reached: u64,
    finished: bool,
}

impl WaypointTracker {
    /// A tracker at the first waypoint. The route must not be empty.
    pub fn new(cfg: RouteConfig) -> Self {
        assert!(
            !cfg.waypoints.is_empty(),
            "a route needs at least one waypoint"
        );
        Self {
            cfg,
            active: 0,
            reached: 0,
            finished: false,
        }
    }

    /// The active waypoint.
    pub fn goal(&self) -> &[f64] {
        &self.cfg.waypoints[self.active]
    }

    /// The active waypoint's first two coordinates, zero-padded (what the
    /// control message carries).
    pub fn goal2(&self) -> [f64; 2] {
        let mut g = [0.0; 2];
        for (o, v) in g.iter_mut().zip(self.goal()) {
            *o = *v;
        }
        g
    }

    /// Number of waypoints reached so far.
    pub fn reached(&self) -> u64 {
        self.reached
    }

    /// Distance from `pos` to the active waypoint.
    pub fn distance(&self, pos: &[f64]) -> f64 {
        self.goal()
            .iter()
            .zip(pos)
            .map(|(g, p)| (p - g) * (p - g))
            .sum::<f64>()
            .sqrt()
    }

    /// Continue a route after a restart: make the waypoint whose first two
    /// coordinates equal `goal` (as the control message carries them)
    /// active (the first one if none is) with `reached` waypoints reached.
    pub fn resume_at(&mut self, goal: [f64; 2], reached: u64) {
        self.active = self
            .cfg
            .waypoints
            .iter()
            .position(|w| w.iter().zip(goal).all(|(a, b)| *a == b))
            .unwrap_or(0);
        self.reached = reached;
    }

    /// Advance if `pos` reached the active waypoint; returns true on a switch.
    pub fn update(&mut self, pos: &[f64]) -> bool {
        if self.finished || self.distance(pos) > self.cfg.reach_radius {
            return false;
        }
        self.reached += 1;
        if self.active + 1 < self.cfg.waypoints.len() {
            self.active += 1;
        } else if self.cfg.cycle {
            self.active = 0;
        } else {
            self.finished = true;
            return false;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn advances_and_cycles() {
        let mut t = WaypointTracker::new(RouteConfig {
            waypoints: vec![vec![0.0, 0.0], vec![3.0, 0.0]],
            reach_radius: 0.5,
            cycle: true,
        });
        assert!(!t.update(&[1.0, 0.0]));
        assert!(t.update(&[0.2, 0.1]));
        assert_eq!(t.goal(), [3.0, 0.0]);
        assert!(t.update(&[2.9, 0.0]));
        assert_eq!(t.goal(), [0.0, 0.0]);
        assert_eq!(t.reached(), 2);
    }

    #[test]
    fn a_one_axis_set_point_is_held_once_reached() {
        let mut t = WaypointTracker::new(RouteConfig {
            waypoints: vec![vec![1.0]],
            reach_radius: 0.1,
            cycle: false,
        });
        assert_eq!(t.distance(&[0.4]), 0.6);
        assert!(!t.update(&[0.8]));
        assert!(!t.update(&[0.95]), "reached, but no switch");
        assert_eq!(t.reached(), 1);
        assert_eq!(t.goal(), [1.0]);
        assert_eq!(t.goal2(), [1.0, 0.0]);
    }
}
