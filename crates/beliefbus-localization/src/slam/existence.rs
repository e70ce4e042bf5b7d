//! Landmark existence from negative information, for the particle SLAM
//! filters (Montemerlo et al.'s FastSLAM "landmark existence" counter,
//! the usual companion of FastSLAM on Victoria Park).
//!
//! Every landmark of every particle carries an evidence e. After the
//! particle's update at its new pose x, for each scan that has returns:
//!
//! ```text
//! new landmark                                     e  = start
//! associated with a return of the scan             e += hit
//! not associated, predicted inside the field of view:
//!     r_min + margin ≤ ‖m − x₁₂‖ ≤ r_max − margin,
//!     b_min + margin/r ≤ h_b(x, m) ≤ b_max − margin/r  e −= miss
//! e ≥ confirm                                      confirmed: never penalised again
//! e ≤ 0                                            removed from the particle's map
//! ```
//!
//! A provisional landmark that the detector does not see again while it
//! should (a clutter detection, a duplicate of a tree) is thus dropped
//! after about start/miss scans; a landmark outside the field of view is
//! never penalised; one seen at a steady rate is confirmed. Occlusion by
//! other trees is not modelled (a hidden tree counts as a miss), which is
//! why only provisional landmarks are ever removed.
//!
//! Evidence lives in a [`SharedMap`] per particle beside the landmarks, so
//! a resampling copy shares its blocks like the map's (memory O(M·N)), and
//! removal is a swap-remove in both: the last landmark takes the removed
//! one's index. That renumbers a particle's landmarks, so existence does
//! not combine with association shared across particles, imposed
//! associations or the resample-move's sighting lists, which all hold
//! landmark indices. The rule draws no random numbers: with every
//! predicted landmark associated the filter's estimates are exactly those
//! without it.

use super::assoc::Association;
use super::map::SharedMap;
use crate::error::LocalizationError;
use crate::geometry::{wrap_angle, Point, Pose};
use std::f64::consts::{FRAC_PI_2, PI};

/// The rule's parameters (evidence in units of one sighting).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExistenceConfig {
    /// Evidence of a landmark when it is started.
    pub start: f32,
    /// Added per scan in which the landmark is associated.
    pub hit: f32,
    /// Removed per scan in which it is predicted in view and not associated.
    pub miss: f32,
    /// Evidence at which a landmark is confirmed for good.
    pub confirm: f32,
    /// Field of view: ranges (m) of the detector.
    pub min_range: f64,
    pub max_range: f64,
    /// Field of view: laser-frame bearings (rad, π/2 straight ahead).
    pub min_bearing: f64,
    pub max_bearing: f64,
    /// A landmark counts as in view only this far (m) inside the edges.
    pub margin: f64,
}

/// Confirmed landmarks carry this evidence.
const CONFIRMED: f32 = f32::INFINITY;

impl ExistenceConfig {
    /// The rule for a forward half circle of radius `max_range`.
    pub fn half_circle(max_range: f64) -> Self {
        Self {
            start: 1.0,
            hit: 1.0,
            miss: 0.25,
            confirm: 3.0,
            min_range: 0.0,
            max_range,
            min_bearing: 0.0,
            max_bearing: PI,
            margin: 1.0,
        }
    }

    /// Check the settings.
    pub fn validate(&self) -> Result<(), LocalizationError> {
        for (name, v) in [
            ("existence start", self.start),
            ("existence hit", self.hit),
            ("existence miss", self.miss),
        ] {
            LocalizationError::positive(name, v as f64)?;
        }
        if !(self.confirm >= self.start) {
            return Err(LocalizationError::Invalid {
                name: "existence confirm",
                value: self.confirm as f64,
                need: "must be ≥ the start evidence",
            });
        }
        LocalizationError::positive("existence max_range", self.max_range)?;
        if !(self.min_range >= 0.0
            && self.min_range < self.max_range
            && self.min_bearing < self.max_bearing
            && self.margin >= 0.0)
        {
            return Err(LocalizationError::Invalid {
                name: "existence field of view",
                value: self.min_range,
                need: "needs 0 ≤ min_range < max_range, min_bearing < max_bearing, margin ≥ 0",
            });
        }
        Ok(())
    }

    /// Whether a landmark at m is predicted inside the field of view from x.
    pub fn in_view(&self, x: &Pose, m: Point) -> bool {
        let d1 = m[0] - x[0];
        let d2 = m[1] - x[1];
        let r = d1.hypot(d2);
        if r < self.min_range + self.margin || r > self.max_range - self.margin {
            return false;
        }
        let b = wrap_angle(d2.atan2(d1) - x[2] + FRAC_PI_2);
        let edge = self.margin / r.max(1e-9);
        b >= self.min_bearing + edge && b <= self.max_bearing - edge
    }

    /// Apply the rule to one particle after its update at pose x: `map` and
    /// `ev` had `before` landmarks before the scan, `assoc` is the scan's
    /// association (indices < `before` for known landmarks; landmarks from
    /// `before` on were started by this scan). Returns how many landmarks
    /// were removed. Writes only the evidence that changes, so unchanged
    /// shared blocks stay shared.
    pub fn apply<L: Clone>(
        &self,
        map: &mut SharedMap<L>,
        ev: &mut SharedMap<f32>,
        before: usize,
        x: &Pose,
        assoc: &[Association],
        pos: impl Fn(&L) -> Point,
    ) -> usize {
        while ev.len() < map.len() {
            ev.push(self.start);
        }
        let mut doomed = false;
        for k in 0..before.min(map.len()) {
            let e = *ev.get(k).expect("k < len");
            if e == CONFIRMED {
                continue;
            }
            let seen = assoc.contains(&Association::Known(k));
            let e2 = if seen {
                let e2 = e + self.hit;
                if e2 >= self.confirm {
                    CONFIRMED
                } else {
                    e2
                }
            } else if self.in_view(x, pos(map.get(k).expect("k < len"))) {
                e - self.miss
            } else {
                continue;
            };
            doomed |= e2 <= 0.0;
            ev.set(k, e2);
        }
        if !doomed {
            return 0;
        }
        // Downwards, so the landmark swapped into k has been visited.
        let mut removed = 0;
        for k in (0..before.min(map.len())).rev() {
            if *ev.get(k).expect("k < len") <= 0.0 {
                map.swap_remove(k);
                ev.swap_remove(k);
                removed += 1;
            }
        }
        removed
    }
}
