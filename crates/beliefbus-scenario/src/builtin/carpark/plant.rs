//! The car park behind the plant stage: a multi-rate plant
//! ([`Plant::next_sample`]) on the data set's two channels. Its samples,
//! in time order:
//!
//! ```text
//! step n (time t_n − t_0):  [laser samples of the scan at step n, if any]
//!                           odometry sample n: (v_l, α) of u_n
//! ```
//!
//! The true pose at every sample of step n is x_n. A scan with more than
//! `max_features` returns keeps the nearest. The wheel speed published is
//! the encoder's, v_l = v_c (L − H tan α) / L, from which the filter
//! recovers v_c.
//!
//! Without a control (estimation only) the plant replays the data set
//! drawn when the system was built: x_n, u_n and the scans are the data
//! set's, the run seed does not enter. Once a steering control arrives
//! (the `pure-pursuit` controller) the plant drives itself from the pose
//! it has reached: the recorded wheel speed with the commanded steering
//! (clamped to ±`control.max_steering`),
//! x_n = x_{n−1} + R(x_{n−1}, u_n) δ_n + ΔB_n with the data set's true-path
//! noise (`truth_noise` × Table 7's), and its laser sees the map from
//! there (range/bearing noise Σ₂) at the data set's scan steps, from the
//! plant's own seeded stream; a scan that then sees nothing is one laser
//! sample with both slots empty.
//!
//! Restarted from a truth (after a crash) it finds the step whose true
//! pose is nearest and continues after it, its clock starting there.

use super::encoding::{write_laser, write_odometry, EMPTY, LASER0, MAX_FEATURES, PER_SAMPLE};
use super::{CarparkSystem, LASER, ODOMETRY};
use crate::rng::SimRng;
use crate::{NextSample, Plant, PLANT_STREAM};
use beliefbus_localization::carpark::{normal3, CarPark};
use beliefbus_localization::geometry::{wrap_angle, Pose};
use beliefbus_localization::laser::{in_view, predict, Observation};
use beliefbus_localization::vehicle::{Control, MotionNoise, StepNoise};
use rand::RngExt;
use rand_distr::StandardNormal;
use std::sync::Arc;

/// What the last [`Plant::step`] took.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Sample {
    Odometry { v_wheel: f64, alpha: f64 },
    Laser { n: usize },
}

/// The plant.
#[derive(Debug)]
pub struct CarparkPlant {
    cp: Arc<CarPark>,
    max_features: usize,
    max_steering: f64,
    max_range: f64,
    /// The true path's noise when driving itself.
    truth_noise: MotionNoise,
    rng: SimRng,
    /// The step being published (its pose is x once `started`).
    n: usize,
    started: bool,
    /// Index into `cp.scans` of the next scan at or after step n.
    scan: usize,
    /// The scan of step n: its features and how many were published.
    buf: [Observation; MAX_FEATURES],
    buf_len: usize,
    buf_sent: usize,
    current: Option<Sample>,
    t_origin: f64,
    x: [f64; 3],
    /// The steering in force (None: replay the data set).
    u: [f64; 1],
    steering: Option<f64>,
}

impl CarparkPlant {
    /// Start at `x0`: the data set's start pose, or a pose of its true path
    /// (a restart) after which the drive continues.
    pub fn new(sys: &CarparkSystem, x0: &[f64], seed: u64) -> Result<Self, String> {
        let cp = sys.carpark.clone();
        if x0.len() != super::STATE || x0.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "carpark plant: the initial state needs {} finite entries",
                super::STATE
            ));
        }
        // The step whose true pose is nearest x0 (exact after a restart
        // of a replay).
        let d2 = |n: usize| {
            let t = cp.truth[n];
            (t[0] - x0[0]).powi(2) + (t[1] - x0[1]).powi(2) + wrap_angle(t[2] - x0[2]).powi(2)
        };
        let at = (0..cp.truth.len())
            .min_by(|&a, &b| d2(a).total_cmp(&d2(b)))
            .unwrap_or(0);
        let s = sys.params.truth_noise * sys.params.truth_noise;
        let m = cp.motion;
        let truth_noise = MotionNoise {
            p: [m.p[0] * s, m.p[1] * s],
            q: [m.q[0] * s, m.q[1] * s, m.q[2] * s],
        };
        let blank = Observation {
            range: 0.0,
            bearing: 0.0,
            landmark: 0,
        };
        Ok(Self {
            max_features: sys.params.max_features,
            max_steering: sys.params.control.max_steering,
            max_range: sys.params.max_range,
            truth_noise,
            rng: crate::rng::stream(seed, PLANT_STREAM),
            n: at + 1,
            started: false,
            scan: cp.scans.partition_point(|sc| sc.step <= at),
            buf: [blank; MAX_FEATURES],
            buf_len: 0,
            buf_sent: 0,
            current: None,
            t_origin: cp.times[at],
            x: [x0[0], x0[1], x0[2]],
            u: [0.0],
            steering: None,
            cp,
        })
    }

    /// Whether step n has a scan.
    fn has_scan(&self) -> bool {
        self.cp
            .scans
            .get(self.scan)
            .is_some_and(|s| s.step == self.n)
    }

    /// Move to x_n and look (the first sample of step n).
    fn start_step(&mut self) {
        let cp = self.cp.clone();
        let n = self.n;
        let rec = cp.controls[n - 1];
        let ute = &cp.ute;
        let v_wheel = rec.v * (ute.l - ute.h * rec.alpha.tan()) / ute.l;
        match self.steering {
            None => {
                let x = cp.truth[n];
                self.x = [x[0], x[1], x[2]];
            }
            Some(a) => {
                let alpha = a.clamp(-self.max_steering, self.max_steering);
                let v = ute.centre_speed(v_wheel, alpha).unwrap_or(rec.v);
                let u = Control { v, alpha };
                let x = Pose::new(self.x[0], self.x[1], self.x[2]);
                let mut next = ute.predict_mean(&x, u);
                if let Ok(sn) = StepNoise::new(ute, u, &self.truth_noise) {
                    next += sn.draw(x[2], &normal3(&mut self.rng));
                }
                self.x = [next[0], next[1], next[2]];
            }
        }
        self.buf_len = 0;
        self.buf_sent = 0;
        if self.has_scan() {
            let sc = cp.scans[self.scan];
            self.scan += 1;
            match self.steering {
                None => {
                    for &o in cp.scan_obs(&sc) {
                        self.keep(o);
                    }
                }
                Some(_) => {
                    let x = Pose::new(self.x[0], self.x[1], self.x[2]);
                    let (sr, sb) = (cp.laser.var_range.sqrt(), cp.laser.var_bearing.sqrt());
                    for (i, &m) in cp.landmarks.iter().enumerate() {
                        if in_view(&x, m, self.max_range) {
                            let (r, b) = predict(&x, m);
                            let e: [f64; 2] = [
                                self.rng.sample(StandardNormal),
                                self.rng.sample(StandardNormal),
                            ];
                            self.keep(Observation {
                                range: r + sr * e[0],
                                bearing: wrap_angle(b + sb * e[1]),
                                landmark: i,
                            });
                        }
                    }
                }
            }
            // Published in landmark order.
            self.buf[..self.buf_len].sort_unstable_by_key(|o| o.landmark);
        }
        self.started = true;
    }

    /// Keep `o` among the nearest `max_features` returns.
    fn keep(&mut self, o: Observation) {
        if self.buf_len < self.max_features {
            self.buf[self.buf_len] = o;
            self.buf_len += 1;
            return;
        }
        let far = (0..self.buf_len)
            .max_by(|&a, &b| self.buf[a].range.total_cmp(&self.buf[b].range))
            .unwrap_or(0);
        if o.range < self.buf[far].range {
            self.buf[far] = o;
        }
    }

    /// Whether step n still has a laser sample to publish (a scan that
    /// sees nothing publishes one empty sample when driving itself).
    fn laser_due(&self) -> bool {
        if !self.started {
            self.has_scan()
        } else {
            self.buf_sent < self.buf_len
        }
    }

    /// Samples left in the data set's steps (not counting scans).
    pub fn remaining_steps(&self) -> usize {
        (self.cp.steps() + 1).saturating_sub(self.n)
    }
}

impl Plant for CarparkPlant {
    fn state(&self) -> &[f64] {
        &self.x
    }
    /// The steering in force (0 while replaying).
    fn control(&self) -> &[f64] {
        &self.u
    }
    fn set_control(&mut self, u: &[f64]) {
        if let Some(&a) = u.first() {
            if a.is_finite() {
                self.u[0] = a;
                self.steering = Some(a);
            }
        }
    }
    /// The vehicle moves at the steps: nothing between samples.
    fn advance(&mut self, _dt: f64) {}
    fn next_sample(&mut self) -> NextSample {
        if self.n > self.cp.steps() {
            return NextSample::Done;
        }
        NextSample::At {
            channel: if self.laser_due() {
                LASER as usize
            } else {
                ODOMETRY as usize
            },
            t: self.cp.times[self.n] - self.t_origin,
        }
    }
    fn step(&mut self) {
        if self.n > self.cp.steps() {
            return;
        }
        let laser = self.laser_due();
        if !self.started {
            self.start_step();
        }
        if laser {
            self.current = Some(Sample::Laser { n: self.buf_sent });
            // At least one sample per scan, even an empty one.
            self.buf_sent = (self.buf_sent + PER_SAMPLE).min(self.buf_len.max(1));
        } else {
            let rec = self.cp.controls[self.n - 1];
            let ute = &self.cp.ute;
            let alpha = match self.steering {
                None => rec.alpha,
                Some(a) => a.clamp(-self.max_steering, self.max_steering),
            };
            self.current = Some(Sample::Odometry {
                v_wheel: rec.v * (ute.l - ute.h * rec.alpha.tan()) / ute.l,
                alpha,
            });
            self.n += 1;
            self.started = false;
        }
    }
    fn measure(&mut self, y: &mut [f64]) {
        match self.current {
            Some(Sample::Odometry { v_wheel, alpha }) => write_odometry(y, v_wheel, alpha),
            Some(Sample::Laser { n }) => {
                if n < self.buf_len {
                    let b = (n + 1 < self.buf_len).then(|| &self.buf[n + 1]);
                    write_laser(y, &self.buf[n], b);
                } else {
                    for k in 0..PER_SAMPLE {
                        let j = LASER0 + 3 * k;
                        y[j..j + 3].copy_from_slice(&[0.0, 0.0, EMPTY]);
                    }
                }
            }
            None => {}
        }
    }
}
