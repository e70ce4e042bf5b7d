//! `scenario_metrics.victoria-park`: the live run's figures, scored as the
//! offline `slam-victoria-park` experiment scores a path.
//!
//! - `gps_rms_m`, `gps_p95_m`: for every kept GPS fix (outliers gated) whose
//!   nearest odometry step the live filter published a belief for, the
//!   distance from the belief's laser point to the fix; RMS and 95th
//!   percentile (`gps_fixes_scored` of them). The antenna's mounting is
//!   undocumented; the data's README finds it near the laser point, which
//!   is compared with GPS directly (as offline);
//! - `dead_reckoning_gps_rms_m`, `…_p95_m`: the mean Ute model driven by the
//!   odometry from the same start, scored at the same fixes;
//! - `map_landmarks`: trees in the filter's map at the last belief (the
//!   belief's component after the pose);
//! - per channel: samples published (truths), beliefs, tree detections;
//!   `steps_reached` and `recorded_s_reached`: how far into the run the
//!   filter got;
//! - `ess_mean`, `ess_min` over the steps that took trees;
//! - time per update (µs, p50 / p99 / mean / max): the filter stage's time
//!   from receiving a sample to publishing its belief, split into SLAM
//!   steps with trees, prediction-only steps, and tree samples (buffering).
//!
//! The odometry step of a belief is its sample's sequence number on the
//! odometry channel + 1 (the plant's first odometry sample is step 1).

use super::data::Run;
use super::{VictoriaParkSystem, LASER, ODOMETRY};
use crate::builtin::carpark::metrics::timing;
use crate::builtin::live_slam::{EMPTY, LASER0, MAP_COMPONENT, PER_SAMPLE, POSE};
use crate::metrics::{BeliefView, RunMetrics, TruthView};
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::vehicle::{Control, Ute};
use serde_json::{json, Value};
use std::sync::Arc;

/// RMS and 95th percentile (None when empty).
fn rms_p95(e: &[f64]) -> (Option<f64>, Option<f64>) {
    if e.is_empty() {
        return (None, None);
    }
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    let mut s = e.to_vec();
    s.sort_by(f64::total_cmp);
    let k = ((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1;
    (Some(rms), Some(s[k]))
}

/// (step, fix) for every kept fix inside the run: the step nearest in time.
pub fn fix_steps(run: &Run) -> Vec<(usize, usize)> {
    let t = &run.times;
    let (t0, tn) = (t[0], t[t.len() - 1]);
    let mut out: Vec<(usize, usize)> = run
        .gps
        .iter()
        .enumerate()
        .filter(|(_, g)| g.time >= t0 && g.time <= tn)
        .map(|(f, g)| {
            let i = t.partition_point(|&x| x < g.time).min(t.len() - 1);
            let j = if i > 0 && (g.time - t[i - 1]) < (t[i] - g.time) {
                i - 1
            } else {
                i
            };
            (j, f)
        })
        .collect();
    out.sort_unstable();
    out
}

/// The mean Ute model driven by the odometry from `start`: the pose at
/// every step.
pub fn dead_reckoning(run: &Run, ute: &Ute, start: Pose) -> Vec<Pose> {
    let mut p = vec![start; run.times.len()];
    for k in 1..run.times.len() {
        let [v_wheel, alpha] = run.odometry[k];
        let u = Ute {
            dt: run.times[k] - run.times[k - 1],
            ..*ute
        };
        p[k] = match u.centre_speed(v_wheel, alpha) {
            Ok(v) => u.predict_mean(&p[k - 1], Control { v, alpha }),
            Err(_) => p[k - 1],
        };
    }
    p
}

/// The accumulator.
pub struct VictoriaParkMetrics {
    run: Arc<Run>,
    particles: usize,
    fixes: Vec<(usize, usize)>,
    dr: Vec<Pose>,
    has_trees: Vec<bool>,
    errors: Vec<f64>,
    dr_errors: Vec<f64>,
    truths: [u64; 3],
    beliefs: [u64; 3],
    detections: u64,
    steps_reached: usize,
    map_landmarks: Option<f64>,
    ess_sum: f64,
    ess_min: f64,
    ess_n: u64,
    tree_step_ns: Vec<u64>,
    predict_ns: Vec<u64>,
    tree_sample_ns: Vec<u64>,
}

fn slot(channel: u32) -> usize {
    match channel {
        ODOMETRY => 0,
        LASER => 1,
        _ => 2,
    }
}

impl VictoriaParkMetrics {
    pub fn new(sys: &VictoriaParkSystem) -> Self {
        let run = sys.run.clone();
        let mut has_trees = vec![false; run.times.len()];
        for s in &run.scans {
            has_trees[s.step] = true;
        }
        let cfg = sys.slam_config();
        Self {
            fixes: fix_steps(&run),
            dr: dead_reckoning(&run, &cfg.model.ute, sys.start),
            has_trees,
            particles: cfg.particles,
            run,
            errors: Vec::new(),
            dr_errors: Vec::new(),
            truths: [0; 3],
            beliefs: [0; 3],
            detections: 0,
            steps_reached: 0,
            map_landmarks: None,
            ess_sum: 0.0,
            ess_min: f64::INFINITY,
            ess_n: 0,
            tree_step_ns: Vec::new(),
            predict_ns: Vec::new(),
            tree_sample_ns: Vec::new(),
        }
    }
}

impl RunMetrics for VictoriaParkMetrics {
    fn truth(&mut self, t: &TruthView) {
        self.truths[slot(t.channel)] += 1;
        if t.channel == LASER && t.y.len() >= LASER0 + 3 * PER_SAMPLE {
            self.detections += (0..PER_SAMPLE)
                .filter(|i| t.y[LASER0 + 3 * i + 2] != EMPTY)
                .count() as u64;
        }
    }

    fn belief(&mut self, b: &BeliefView, t: &TruthView) {
        self.beliefs[slot(b.sensor_channel)] += 1;
        match b.sensor_channel {
            ODOMETRY if b.mean.len() >= POSE => {
                let k = t.seq as usize + 1;
                if k >= self.run.times.len() {
                    return;
                }
                self.steps_reached = self.steps_reached.max(k);
                if let Some(&m) = b.mean.get(MAP_COMPONENT) {
                    self.map_landmarks = Some(m);
                }
                let from = self.fixes.partition_point(|&(s, _)| s < k);
                for &(_, f) in self.fixes[from..].iter().take_while(|&&(s, _)| s == k) {
                    let g = self.run.gps[f];
                    self.errors.push((b.mean[0] - g.x).hypot(b.mean[1] - g.y));
                    self.dr_errors
                        .push((self.dr[k][0] - g.x).hypot(self.dr[k][1] - g.y));
                }
                if self.has_trees[k] {
                    self.tree_step_ns.push(b.filter_ns);
                    self.ess_sum += b.ess;
                    self.ess_min = self.ess_min.min(b.ess);
                    self.ess_n += 1;
                } else {
                    self.predict_ns.push(b.filter_ns);
                }
            }
            LASER => self.tree_sample_ns.push(b.filter_ns),
            _ => {}
        }
    }

    fn report(&self) -> Value {
        let (rms, p95) = rms_p95(&self.errors);
        let (dr_rms, dr_p95) = rms_p95(&self.dr_errors);
        let ess_mean = (self.ess_n > 0).then(|| self.ess_sum / self.ess_n as f64);
        let ess_min = (self.ess_n > 0).then_some(self.ess_min);
        let m = self.particles as f64;
        let t0 = self.run.times[0];
        json!({
            "particles": self.particles,
            "channels": {
                "odometry": {"id": ODOMETRY, "samples": self.truths[0], "beliefs": self.beliefs[0]},
                "laser": {"id": LASER, "samples": self.truths[1], "beliefs": self.beliefs[1],
                          "detections": self.detections},
                "other": {"samples": self.truths[2], "beliefs": self.beliefs[2]},
            },
            "steps_in_run": self.run.steps(),
            "steps_reached": self.steps_reached,
            "recorded_s_reached": self.run.times[self.steps_reached] - t0,
            "gps_fixes_scored": self.errors.len(),
            "gps_rms_m": rms,
            "gps_p95_m": p95,
            "dead_reckoning_gps_rms_m": dr_rms,
            "dead_reckoning_gps_p95_m": dr_p95,
            "gps_fixes_dropped_as_outliers": self.run.gps_dropped,
            "map_landmarks": self.map_landmarks,
            "tree_steps": self.ess_n,
            "ess_mean": ess_mean,
            "ess_min": ess_min,
            "ess_mean_fraction": ess_mean.map(|e| e / m),
            "time_tree_step": timing(&self.tree_step_ns),
            "time_prediction_step": timing(&self.predict_ns),
            "time_tree_sample": timing(&self.tree_sample_ns),
        })
    }
}
