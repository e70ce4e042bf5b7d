//! The plant: the recorded run streamed through the sensor ABI on two
//! channels, each sample at its recorded time divided by the speed-up:
//!
//! ```text
//! step k (time (t_k − t_0)/s):  [tree samples of the scans of step k, at the scans' own times]
//!                               odometry sample k: (v_l, α)
//! ```
//!
//! A scan of n detections is ⌈n/2⌉ laser samples of two (range, bearing,
//! diameter) slots each; the samples of one scan are spread 1 µs apart
//! before the scan's time (so they keep their order and pass ingest's rate
//! check at `max_rate_hz` ≥ 1 MHz), never before the previous sample.
//!
//! The recorded run has no true pose. The plant's "truth" is the GPS
//! reference: (x, y) of the latest kept GPS fix at or before the sample
//! (the first fix before it), β = 0 (not measured). The run metrics score
//! the filter against the GPS fixes themselves; see [`super::metrics`].
//! Nothing drives the vehicle: a control is recorded and ignored. A
//! restarted plant streams the run again from its start.

use super::data::Run;
use super::{LASER, ODOMETRY};
use crate::builtin::live_slam::{EMPTY, LASER0, PER_SAMPLE};
use crate::{NextSample, Plant};
use std::sync::Arc;

/// Spacing of the samples of one scan (pipeline seconds).
const STAGGER: f64 = 1e-6;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Sample {
    Odometry(usize),
    /// Scan index and first detection of the sample.
    Laser(usize, usize),
}

/// The plant.
#[derive(Debug)]
pub struct VictoriaParkPlant {
    run: Arc<Run>,
    speedup: f64,
    /// The next odometry step, the next scan and its detections sent.
    k: usize,
    scan: usize,
    sent: usize,
    current: Option<Sample>,
    last_t: f64,
    gps: usize,
    x: [f64; 3],
    u: [f64; 1],
}

impl VictoriaParkPlant {
    pub fn new(run: Arc<Run>, speedup: f64) -> Result<Self, String> {
        if !(speedup.is_finite() && speedup > 0.0) {
            return Err(format!("speedup must be > 0, got {speedup}"));
        }
        let g = run.gps.first().ok_or("the run has no GPS fix")?;
        let x = [g.x, g.y, 0.0];
        Ok(Self {
            run,
            speedup,
            k: 1,
            scan: 0,
            sent: 0,
            current: None,
            last_t: 0.0,
            gps: 0,
            x,
            u: [0.0],
        })
    }

    /// Pipeline time of data-set time `t`.
    fn at(&self, t: f64) -> f64 {
        (t - self.run.times[0]) / self.speedup
    }

    /// When the next sample is measured (pipeline seconds).
    fn next_time(&self) -> f64 {
        if self.laser_due() {
            let s = &self.run.scans[self.scan];
            let samples = s.len.div_ceil(PER_SAMPLE);
            let j = self.sent / PER_SAMPLE;
            (self.at(s.time) - (samples - 1 - j) as f64 * STAGGER).max(self.last_t)
        } else {
            self.at(self.run.times[self.k])
        }
    }

    fn laser_due(&self) -> bool {
        self.run
            .scans
            .get(self.scan)
            .is_some_and(|s| s.step == self.k)
    }

    /// The GPS reference at data-set time `t`.
    fn follow_gps(&mut self, t: f64) {
        let gps = &self.run.gps;
        while self.gps + 1 < gps.len() && gps[self.gps + 1].time <= t {
            self.gps += 1;
        }
        self.x = [gps[self.gps].x, gps[self.gps].y, 0.0];
    }
}

impl Plant for VictoriaParkPlant {
    /// The GPS reference (see the module doc).
    fn state(&self) -> &[f64] {
        &self.x
    }
    fn control(&self) -> &[f64] {
        &self.u
    }
    fn set_control(&mut self, u: &[f64]) {
        if let Some(&a) = u.first() {
            self.u[0] = a;
        }
    }
    fn advance(&mut self, _dt: f64) {}
    fn next_sample(&mut self) -> NextSample {
        if self.k > self.run.steps() {
            return NextSample::Done;
        }
        let t = self.next_time();
        NextSample::At {
            channel: if self.laser_due() {
                LASER as usize
            } else {
                ODOMETRY as usize
            },
            t,
        }
    }
    fn step(&mut self) {
        if self.k > self.run.steps() {
            return;
        }
        self.last_t = self.next_time();
        let data_t = if self.laser_due() {
            let s = self.run.scans[self.scan];
            self.current = Some(Sample::Laser(self.scan, self.sent));
            self.sent += PER_SAMPLE;
            if self.sent >= s.len {
                self.scan += 1;
                self.sent = 0;
            }
            s.time
        } else {
            self.current = Some(Sample::Odometry(self.k));
            self.k += 1;
            self.run.times[self.k - 1]
        };
        self.follow_gps(data_t);
    }
    fn measure(&mut self, y: &mut [f64]) {
        match self.current {
            Some(Sample::Odometry(k)) => {
                y[0] = self.run.odometry[k][0];
                y[1] = self.run.odometry[k][1];
            }
            Some(Sample::Laser(s, from)) => {
                let trees = self.run.scan_trees(&self.run.scans[s]);
                for i in 0..PER_SAMPLE {
                    let j = LASER0 + 3 * i;
                    let v = match trees.get(from + i) {
                        Some(t) => [t.range, t.bearing, t.diameter],
                        None => [0.0, 0.0, EMPTY],
                    };
                    y[j..j + 3].copy_from_slice(&v);
                }
            }
            None => {}
        }
    }
}
