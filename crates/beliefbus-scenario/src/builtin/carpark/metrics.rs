//! `scenario_metrics.carpark`: the live run's figures.
//!
//! - per channel: samples the plant published (its truths), beliefs the
//!   filter published for them, and the laser features carried;
//! - `pose_rmse_position_m`, `pose_rmse_heading_rad`: over the counted
//!   odometry-channel beliefs (one per MCL step; a laser sample's belief is
//!   the unchanged previous one), √mean ‖p̂ − p‖² and √mean wrap(β̂ − β)²;
//! - `dead_reckoning_*`: the same for the odometry integrated with the
//!   motion model's mean, x_n = x_{n−1} + R(x_{n−1}, u_n) δ_n, from the
//!   true start pose (the filter's prior mean) at the same samples — what
//!   the filter would give without the laser;
//! - `ess_mean`, `ess_min` (and over M): the ESS of the laser steps'
//!   weights before resampling;
//! - time per update (µs, p50 / p99 / mean / max): the filter stage's time
//!   from receiving an observation to publishing its belief
//!   (t_filter_out − t_filter_in), split into laser steps (the odometry
//!   sample that applied a scan: measured at the scan's time), prediction
//!   steps, and laser samples (buffering only);
//! - `controls`, `controlled_fraction`: controls computed (not the stage's
//!   fallback) from odometry-sample beliefs, over odometry samples
//!   published (controls after laser samples are counted apart);
//! - `map_landmarks` (SLAM backends): the landmark count of the filter's
//!   map at the last belief (the belief's component after the pose), and
//!   `landmarks_seen`: the distinct true landmarks the published scans
//!   reported (what a perfect map would hold); null for MCL;
//! - `path_rmse_m`: the true laser point's distance to the data set's path
//!   (what `pure-pursuit` follows; 0 while replaying it), over the counted
//!   odometry samples.

use super::encoding::{read_slot, LASER0};
use super::{CarparkSystem, LASER, ODOMETRY, STATE};
use crate::metrics::{BeliefView, ControlView, RunMetrics, TruthView};
use beliefbus_localization::carpark::CarPark;
use beliefbus_localization::geometry::{wrap_angle, Pose};
use beliefbus_localization::vehicle::{Control, Ute};
use serde_json::{json, Value};
use std::sync::Arc;

/// Scan times remembered.
const SCAN_RING: usize = 16;

/// Squared errors and their count.
#[derive(Clone, Copy, Debug, Default)]
struct Errors {
    pos: f64,
    heading: f64,
    n: u64,
}

impl Errors {
    fn add(&mut self, est: &[f64], x: &[f64]) {
        self.pos += (est[0] - x[0]).powi(2) + (est[1] - x[1]).powi(2);
        self.heading += wrap_angle(est[2] - x[2]).powi(2);
        self.n += 1;
    }
    fn rms(&self) -> (Option<f64>, Option<f64>) {
        let n = self.n as f64;
        (
            (self.n > 0).then(|| (self.pos / n).sqrt()),
            (self.n > 0).then(|| (self.heading / n).sqrt()),
        )
    }
}

/// Percentiles of a list of durations (ns) in µs.
pub(crate) fn timing(ns: &[u64]) -> Value {
    if ns.is_empty() {
        return json!({"n": 0});
    }
    let mut v = ns.to_vec();
    v.sort_unstable();
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize] as f64 / 1e3;
    let mean = v.iter().sum::<u64>() as f64 / v.len() as f64 / 1e3;
    json!({"n": v.len(), "p50_us": q(0.5), "p99_us": q(0.99), "mean_us": mean, "max_us": q(1.0)})
}

/// The accumulator.
pub struct CarparkMetrics {
    cp: Arc<CarPark>,
    /// Controls computed from odometry beliefs, from laser beliefs, and
    /// the stage's fallbacks.
    controls: u64,
    laser_controls: u64,
    fallbacks: u64,
    path_index: usize,
    path_se: f64,
    ute: Ute,
    sample_dt: f64,
    particles: usize,
    /// Truths and beliefs per channel (odometry, laser, other).
    truths: [u64; 3],
    beliefs: [u64; 3],
    features: u64,
    filter: Errors,
    dead_reckoning: Errors,
    /// Dead reckoning's pose and the time of its last odometry sample.
    dr: Pose,
    dr_time: Option<u64>,
    /// Measurement times of the latest scans (a belief may be scored
    /// after later truths arrived).
    scan_ns: [u64; SCAN_RING],
    scans: usize,
    ess_sum: f64,
    ess_min: f64,
    ess_n: u64,
    laser_step_ns: Vec<u64>,
    predict_ns: Vec<u64>,
    laser_sample_ns: Vec<u64>,
    /// Landmarks the scans reported, and the filter's map size.
    seen: Vec<bool>,
    map_landmarks: Option<f64>,
}

fn slot(channel: u32) -> usize {
    match channel {
        ODOMETRY => 0,
        LASER => 1,
        _ => 2,
    }
}

impl CarparkMetrics {
    pub fn new(sys: &CarparkSystem) -> Self {
        let x0 = sys.carpark.truth[0];
        Self {
            cp: sys.carpark.clone(),
            controls: 0,
            laser_controls: 0,
            fallbacks: 0,
            path_index: 0,
            path_se: 0.0,
            ute: sys.carpark.ute,
            sample_dt: sys.sample_dt,
            particles: sys.params.filter.particles,
            truths: [0; 3],
            beliefs: [0; 3],
            features: 0,
            filter: Errors::default(),
            dead_reckoning: Errors::default(),
            dr: x0,
            dr_time: None,
            scan_ns: [0; SCAN_RING],
            scans: 0,
            ess_sum: 0.0,
            ess_min: f64::INFINITY,
            ess_n: 0,
            laser_step_ns: Vec::new(),
            predict_ns: Vec::new(),
            laser_sample_ns: Vec::new(),
            seen: vec![false; sys.carpark.landmarks.len()],
            map_landmarks: None,
        }
    }
}

impl RunMetrics for CarparkMetrics {
    fn truth(&mut self, t: &TruthView) {
        self.truths[slot(t.channel)] += 1;
        match t.channel {
            ODOMETRY if t.y.len() >= 2 && t.x.len() >= STATE => {
                let dt = match self.dr_time {
                    None => self.sample_dt,
                    Some(prev) => t.t_ns.saturating_sub(prev) as f64 * 1e-9,
                };
                self.dr_time = Some(t.t_ns);
                if let Ok(v) = self.ute.centre_speed(t.y[0], t.y[1]) {
                    let ute = Ute { dt, ..self.ute };
                    self.dr = ute.predict_mean(&self.dr, Control { v, alpha: t.y[1] });
                }
                let (i, d) = super::control::nearest(&self.cp, self.path_index, t.x[0], t.x[1]);
                self.path_index = i;
                if t.counted {
                    self.dead_reckoning.add(self.dr.as_slice(), t.x);
                    self.path_se += d * d;
                }
            }
            LASER if t.y.len() > LASER0 + 5 => {
                if self.scans == 0 || self.scan_ns[(self.scans - 1) % SCAN_RING] != t.t_ns {
                    self.scan_ns[self.scans % SCAN_RING] = t.t_ns;
                    self.scans += 1;
                }
                for i in 0..2 {
                    if let Ok(Some(o)) = read_slot(t.y, i, usize::MAX) {
                        self.features += 1;
                        if let Some(s) = self.seen.get_mut(o.landmark) {
                            *s = true;
                        }
                    }
                }
            }
            _ => {}
        }
    }

    fn belief(&mut self, b: &BeliefView, t: &TruthView) {
        self.beliefs[slot(b.sensor_channel)] += 1;
        match b.sensor_channel {
            ODOMETRY if b.mean.len() >= STATE && t.x.len() >= STATE => {
                self.filter.add(b.mean, t.x);
                if let Some(&m) = b.mean.get(STATE) {
                    self.map_landmarks = Some(m);
                }
                if self.scan_ns[..self.scans.min(SCAN_RING)].contains(&t.t_ns) {
                    self.laser_step_ns.push(b.filter_ns);
                    self.ess_sum += b.ess;
                    self.ess_min = self.ess_min.min(b.ess);
                    self.ess_n += 1;
                } else {
                    self.predict_ns.push(b.filter_ns);
                }
            }
            LASER => self.laser_sample_ns.push(b.filter_ns),
            _ => {}
        }
    }

    fn control(&mut self, c: &ControlView) {
        match (c.ok, c.sensor_channel) {
            (true, ODOMETRY) => self.controls += 1,
            (true, _) => self.laser_controls += 1,
            (false, _) => self.fallbacks += 1,
        }
    }

    fn report(&self) -> Value {
        let (pos, heading) = self.filter.rms();
        let (dr_pos, dr_heading) = self.dead_reckoning.rms();
        let ess_mean = (self.ess_n > 0).then(|| self.ess_sum / self.ess_n as f64);
        let ess_min = (self.ess_n > 0).then_some(self.ess_min);
        let m = self.particles as f64;
        json!({
            "particles": self.particles,
            "channels": {
                "odometry": {"id": ODOMETRY, "samples": self.truths[0], "beliefs": self.beliefs[0]},
                "laser": {"id": LASER, "samples": self.truths[1], "beliefs": self.beliefs[1],
                          "features": self.features},
                "other": {"samples": self.truths[2], "beliefs": self.beliefs[2]},
            },
            "pose_rmse_position_m": pos,
            "pose_rmse_heading_rad": heading,
            "pose_steps": self.filter.n,
            "dead_reckoning_rmse_position_m": dr_pos,
            "dead_reckoning_rmse_heading_rad": dr_heading,
            "laser_steps": self.ess_n,
            "ess_mean": ess_mean,
            "ess_min": ess_min,
            "ess_mean_fraction": ess_mean.map(|e| e / m),
            "ess_min_fraction": ess_min.map(|e| e / m),
            "time_laser_step": timing(&self.laser_step_ns),
            "time_prediction_step": timing(&self.predict_ns),
            "time_laser_sample": timing(&self.laser_sample_ns),
            "controls": self.controls,
            "controls_on_laser_samples": self.laser_controls,
            "control_fallbacks": self.fallbacks,
            "controlled_fraction": (self.truths[0] > 0)
                .then(|| self.controls as f64 / self.truths[0] as f64),
            "map_landmarks": self.map_landmarks,
            "landmarks_seen": self.map_landmarks
                .map(|_| self.seen.iter().filter(|&&s| s).count()),
            "path_rmse_m": (self.dead_reckoning.n > 0)
                .then(|| (self.path_se / self.dead_reckoning.n as f64).sqrt()),
        })
    }
}
