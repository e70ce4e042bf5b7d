//! Running a SLAM filter over a synthetic car park (paper 003 §4.2.1): at
//! each scan the virtual laser reports one of the visible landmarks, picked
//! at random ("if more than one feature is detected, one is selected at
//! random"), without its identity; the filter steps once per odometry
//! sample with the step's own length.

use super::assoc::{Association, RangeBearing};
use super::SlamFilter;
use crate::carpark::CarPark;
use crate::error::LocalizationError;
use crate::geometry::Pose;
use beliefbus_core::rng::SimRng;
use rand::RngExt;

/// One return handed to the filter at a step, with its true landmark (for
/// scoring only).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pick {
    pub step: usize,
    pub z: RangeBearing,
    pub landmark: usize,
}

/// One visible landmark per scan, chosen uniformly with `rng`.
pub fn pick_one_per_scan(cp: &CarPark, rng: &mut SimRng) -> Vec<Pick> {
    cp.scans
        .iter()
        .map(|s| {
            let obs = cp.scan_obs(s);
            let o = obs[rng.random_range(0..obs.len())];
            Pick {
                step: s.step,
                z: RangeBearing {
                    range: o.range,
                    bearing: o.bearing,
                },
                landmark: o.landmark,
            }
        })
        .collect()
}

/// Run `filter` from the true start pose over the data set with the given
/// returns; `each(n, estimate)` after every step n = 1..=N.
pub fn run_carpark(
    filter: &mut dyn SlamFilter,
    cp: &CarPark,
    picks: &[Pick],
    rng: &mut SimRng,
    mut each: impl FnMut(usize, &Pose),
) -> Result<(), LocalizationError> {
    run_carpark_with(filter, cp, picks, rng, &RunOptions::default(), |n, e, _| {
        each(n, e)
    })
}

/// Ablations and diagnostics of a run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunOptions {
    /// Hand every filter the true association (the landmark's index in the
    /// order of first sighting, the same in every particle's map) instead
    /// of the ML rule.
    pub known_association: bool,
    /// Particle filters associate each return once for the whole set
    /// ([`super::shared_assoc`]) instead of once per particle.
    pub shared_association: bool,
    /// `(step, slot)`: label the particles' ancestors in `slot` just after
    /// step `step` ([`SlamFilter::mark_ancestors`]).
    pub marks: Vec<(usize, usize)>,
}

/// [`run_carpark`] with options; `each(n, estimate, filter)` after every step.
pub fn run_carpark_with(
    filter: &mut dyn SlamFilter,
    cp: &CarPark,
    picks: &[Pick],
    rng: &mut SimRng,
    opt: &RunOptions,
    mut each: impl FnMut(usize, &Pose, &dyn SlamFilter),
) -> Result<(), LocalizationError> {
    filter.set_shared_association(opt.shared_association);
    filter.reset(&cp.truth[0]);
    let mut order: Vec<usize> = Vec::new();
    let mut it = picks.iter().peekable();
    for n in 1..=cp.steps() {
        let dt = cp.times[n] - cp.times[n - 1];
        let est = match it.next_if(|p| p.step == n) {
            Some(p) => {
                filter.set_true_landmarks(&[p.landmark]);
                if opt.known_association {
                    let a = match order.iter().position(|&l| l == p.landmark) {
                        Some(k) => Association::Known(k),
                        None => {
                            order.push(p.landmark);
                            Association::New
                        }
                    };
                    filter.force_association(&[a]);
                }
                filter.step(cp.controls[n - 1], dt, std::slice::from_ref(&p.z), rng)?
            }
            None => {
                filter.set_true_landmarks(&[]);
                filter.step(cp.controls[n - 1], dt, &[], rng)?
            }
        };
        for &(_, slot) in opt.marks.iter().filter(|m| m.0 == n) {
            filter.mark_ancestors(slot);
        }
        each(n, &est, filter);
    }
    Ok(())
}

/// ‖p̂ − p‖/‖p‖ in % over the laser positions of steps 1..=N.
pub fn trajectory_error_pct(truth: &[Pose], est: &[Pose]) -> f64 {
    let (mut se, mut st) = (0.0, 0.0);
    for (t, e) in truth.iter().zip(est).skip(1) {
        se += (e[0] - t[0]).powi(2) + (e[1] - t[1]).powi(2);
        st += t[0] * t[0] + t[1] * t[1];
    }
    100.0 * (se / st).sqrt()
}
