//! The car park behind the plant stage: a multi-rate plant
//! ([`Plant::next_sample`]) that replays the drawn data set on its two
//! channels. Its samples, in time order:
//!
//! ```text
//! step n (time t_n − t_0):  [laser samples of the scan at step n, if any]
//!                           odometry sample n: (v_l, α) of u_n
//! ```
//!
//! The true pose at every sample of step n is x_n. A scan with more than
//! `max_features` returns keeps the nearest. The wheel speed published is
//! the encoder's, v_l = v_c (L − H tan α) / L, from which the filter
//! recovers v_c. The data set was drawn when the system was built; the
//! plant adds no noise of its own (the run seed does not enter).
//!
//! Restarted from a truth (after a crash) it finds the step whose true
//! pose that is and continues after it, its clock starting there.

use super::encoding::{write_laser, write_odometry, PER_SAMPLE};
use super::{CarparkSystem, LASER, ODOMETRY};
use crate::{NextSample, Plant};
use beliefbus_localization::carpark::CarPark;
use std::sync::Arc;

/// What a sample carries.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Odometry,
    /// Observations `a` and optionally `b` (indices into `CarPark::obs`).
    Laser {
        a: usize,
        b: Option<usize>,
    },
}

/// One sample of the replay.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Event {
    step: usize,
    kind: Kind,
}

/// The replaying plant.
#[derive(Debug)]
pub struct CarparkPlant {
    cp: Arc<CarPark>,
    events: Vec<Event>,
    /// Index of the next event.
    next: usize,
    /// The event taken by the last [`Plant::step`].
    current: Option<Event>,
    /// Data-set time of the plant's time 0.
    t_origin: f64,
    x: [f64; 3],
}

/// The events of the data set from step `from` on.
fn schedule(cp: &CarPark, max_features: usize, from: usize) -> Vec<Event> {
    let mut events = Vec::with_capacity(cp.steps() + 2 * cp.scans.len());
    let mut scans = cp.scans.iter().skip_while(|s| s.step < from).peekable();
    let mut idx: Vec<usize> = Vec::new();
    for step in from..=cp.steps() {
        if let Some(s) = scans.next_if(|s| s.step == step) {
            idx.clear();
            idx.extend(s.start..s.start + s.len);
            // The nearest first, then back in landmark order.
            idx.sort_by(|&i, &j| cp.obs[i].range.total_cmp(&cp.obs[j].range));
            idx.truncate(max_features);
            idx.sort_unstable();
            for pair in idx.chunks(PER_SAMPLE) {
                events.push(Event {
                    step,
                    kind: Kind::Laser {
                        a: pair[0],
                        b: pair.get(1).copied(),
                    },
                });
            }
        }
        events.push(Event {
            step,
            kind: Kind::Odometry,
        });
    }
    events
}

impl CarparkPlant {
    /// Start at `x0`: the data set's start pose, or a pose of its true path
    /// (a restart) after which the replay continues.
    pub fn new(sys: &CarparkSystem, x0: &[f64]) -> Result<Self, String> {
        let cp = sys.carpark.clone();
        if x0.len() != super::STATE || x0.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "carpark plant: the initial state needs {} finite entries",
                super::STATE
            ));
        }
        // The step whose true pose is nearest x0 (exact after a restart).
        let d2 = |n: usize| {
            let t = cp.truth[n];
            (t[0] - x0[0]).powi(2) + (t[1] - x0[1]).powi(2) + (t[2] - x0[2]).powi(2)
        };
        let at = (0..cp.truth.len())
            .min_by(|&a, &b| d2(a).total_cmp(&d2(b)))
            .unwrap_or(0);
        let x = cp.truth[at];
        Ok(Self {
            events: schedule(&cp, sys.params.max_features, at + 1),
            next: 0,
            current: None,
            t_origin: cp.times[at],
            x: [x[0], x[1], x[2]],
            cp,
        })
    }

    /// Samples left to publish.
    pub fn remaining(&self) -> usize {
        self.events.len() - self.next
    }
}

impl Plant for CarparkPlant {
    fn state(&self) -> &[f64] {
        &self.x
    }
    /// Estimation only: no control input.
    fn control(&self) -> &[f64] {
        &[]
    }
    fn set_control(&mut self, _u: &[f64]) {}
    /// The path is the data set's: nothing moves between samples.
    fn advance(&mut self, _dt: f64) {}
    fn next_sample(&mut self) -> NextSample {
        match self.events.get(self.next) {
            None => NextSample::Done,
            Some(e) => NextSample::At {
                channel: match e.kind {
                    Kind::Odometry => ODOMETRY as usize,
                    Kind::Laser { .. } => LASER as usize,
                },
                t: self.cp.times[e.step] - self.t_origin,
            },
        }
    }
    fn step(&mut self) {
        if let Some(&e) = self.events.get(self.next) {
            self.next += 1;
            let x = self.cp.truth[e.step];
            self.x = [x[0], x[1], x[2]];
            self.current = Some(e);
        }
    }
    fn measure(&mut self, y: &mut [f64]) {
        let Some(e) = self.current else {
            return;
        };
        let cp = &self.cp;
        match e.kind {
            Kind::Odometry => {
                let u = cp.controls[e.step - 1];
                let ute = &cp.ute;
                let v_l = u.v * (ute.l - ute.h * u.alpha.tan()) / ute.l;
                write_odometry(y, v_l, u.alpha);
            }
            Kind::Laser { a, b } => write_laser(y, &cp.obs[a], b.map(|b| &cp.obs[b])),
        }
    }
}
