//! The live scenario `victoria-park`: the real Victoria Park run (Guivant
//! & Nebot, ACFR; 26 minutes of a utility vehicle in a Sydney park) streamed
//! through the sensor ABI into the live pipeline running online SLAM
//! (paper 003 §4.2 on real data), each sample at its recorded time divided
//! by `speedup` ([`plant`]):
//!
//! - channel 0, `odometry`, 40 Hz × speed-up: wheel speed v_l (m/s, rear
//!   left encoder) and steering α (rad), components 0, 1;
//! - channel 1, `laser`, the ACFR detector's tree features at the recorded
//!   scan times (≈ 4.7 Hz × speed-up): two per sample, components 2–7 =
//!   (r₁, b₁, d₁, r₂, b₂, d₂), range (m), bearing (rad, laser frame, π/2
//!   ahead) and trunk diameter (m); an empty slot is (0, 0, −1).
//!
//! Filter backends `implicit-slam`, `implicit-refine-slam`, `fastslam2`, `ekf-slam`
//! ([`super::live_slam`]): the same filters, models, gates and start as the
//! offline `beliefbus experiment slam-victoria-park` (state: the laser
//! point; start: the first kept GPS fix, heading `start_heading_deg`). The
//! filter multiplies the pipeline's time steps by the speed-up to recover
//! the recorded ones. The report's `scenario_metrics.victoria-park`
//! ([`metrics`]) scores the estimate against GPS as the offline experiment
//! does.
//!
//! The data are third-party and read in place from `data_dir` (empty:
//! $BELIEFBUS_VICTORIA_PARK, else ../shared/data/victoria-park relative to
//! the working directory); nothing is copied. Without them the build fails
//! with a message saying where to get them.

pub mod data;
pub mod metrics;
pub mod plant;

use super::live_slam::{self, LiveSlamConfig};
use crate::backends::FilterContext;
use crate::metrics::RunMetrics;
use crate::model::Dims;
use crate::{BuildContext, DiscreteSpec, Dynamics, Plant, Scenario, SensorChannel, System};
use beliefbus_core::filter::BayesFilter;
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::laser::LaserNoise;
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::slam::assoc::AssocConfig;
use beliefbus_localization::slam::SlamModel;
use beliefbus_localization::vehicle::{MotionNoise, Ute};
use beliefbus_localization::victoria;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Channel ids.
pub const ODOMETRY: u32 = 0;
pub const LASER: u32 = 1;

/// `[victoria-park]`: the data, the speed-up and the models (the offline
/// experiment's defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct VictoriaParkParams {
    /// Victoria Park folder (odometry.csv, gps.csv,
    /// derived/trees_detectTreesI16.csv), read in place; empty:
    /// $BELIEFBUS_VICTORIA_PARK, else ../shared/data/victoria-park.
    pub data_dir: String,
    /// Recorded seconds per second of the live run.
    pub speedup: f64,
    /// Stop streaming at this time on the data set's clock (s); the run
    /// starts at its first odometry sample (21.94 s).
    pub end_time_s: f64,
    /// Initial heading (degrees from east, counter-clockwise).
    pub start_heading_deg: f64,
    /// Use tree detections up to this range (m); the new-landmark prior's
    /// radius too.
    pub max_range: f64,
    /// Drop a GPS fix implying a higher speed (m/s) from the last kept one.
    pub gps_max_speed: f64,
    /// `[victoria-park.noise]`.
    pub noise: VictoriaParkNoise,
    /// `[victoria-park.filter]`.
    pub filter: VictoriaParkFilter,
}

/// `[victoria-park.noise]`: process and laser noise, association gates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct VictoriaParkNoise {
    /// P11: speed noise intensity (m²/s).
    pub p_speed: f64,
    /// P22: steering noise intensity (rad² s).
    pub p_steer: f64,
    /// Q11 = Q22: position noise intensity (m²/s).
    pub q_pos: f64,
    /// Q33: heading noise intensity (rad²/s).
    pub q_heading: f64,
    /// Variance of a tree's range (m²).
    pub laser_var_range: f64,
    /// Variance of a tree's bearing (rad²).
    pub laser_var_bearing: f64,
    /// Association gate on d².
    pub gate: f64,
    /// Start a landmark when every d² exceeds this.
    pub new_threshold: f64,
    /// Pre-filter radius of the association (m).
    pub assoc_radius: f64,
}

/// `[victoria-park.filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct VictoriaParkFilter {
    /// Samples M of the particle filters.
    pub particles: usize,
    /// Resample when ESS < this fraction of M.
    pub ess_threshold: f64,
    /// Implicit SLAM: Newton steps at most.
    pub newton_max_iter: usize,
    /// Implicit SLAM: stop when the Newton decrement falls below this.
    pub newton_tol: f64,
}

impl Default for VictoriaParkParams {
    /// `beliefbus experiment slam-victoria-park`'s defaults, at 10×.
    fn default() -> Self {
        let ad = AssocConfig::default();
        let nd = NewtonSettings::default();
        Self {
            data_dir: String::new(),
            speedup: 10.0,
            end_time_s: 1e9,
            start_heading_deg: 36.0,
            max_range: 30.0,
            gps_max_speed: 10.0,
            noise: VictoriaParkNoise {
                p_speed: 0.5,
                p_steer: 0.05,
                q_pos: 0.1,
                q_heading: MotionNoise::default().q[2],
                laser_var_range: 0.25,
                laser_var_bearing: 1f64.to_radians().powi(2),
                gate: ad.gate,
                new_threshold: ad.new_threshold,
                assoc_radius: ad.radius,
            },
            filter: VictoriaParkFilter {
                particles: 100,
                ess_threshold: 0.5,
                newton_max_iter: nd.max_iter,
                newton_tol: nd.tol,
            },
        }
    }
}

impl VictoriaParkParams {
    /// The SLAM model (validated).
    pub fn model(&self) -> Result<SlamModel, String> {
        let n = &self.noise;
        let model = SlamModel {
            ute: Ute::default(),
            motion: MotionNoise {
                p: [n.p_speed, n.p_steer],
                q: [n.q_pos, n.q_pos, n.q_heading],
            },
            laser: LaserNoise {
                var_range: n.laser_var_range,
                var_bearing: n.laser_var_bearing,
            },
            assoc: AssocConfig {
                gate: n.gate,
                new_threshold: n.new_threshold,
                radius: n.assoc_radius,
            },
            max_range: self.max_range,
        };
        model.validate().map_err(|e| e.to_string())?;
        Ok(model)
    }

    fn validate(&self) -> Result<(), String> {
        if !(self.speedup.is_finite() && self.speedup > 0.0 && self.speedup <= 1000.0) {
            return Err(format!(
                "speedup must be in (0, 1000], got {}",
                self.speedup
            ));
        }
        if !(self.gps_max_speed > 0.0 && self.start_heading_deg.is_finite()) {
            return Err("gps_max_speed must be > 0 and start_heading_deg finite".into());
        }
        let f = &self.filter;
        if !(1..=100_000).contains(&f.particles) || !(0.0..=1.0).contains(&f.ess_threshold) {
            return Err(format!(
                "filter.particles must be in 1..=100000 and filter.ess_threshold in [0, 1], got {} and {}",
                f.particles, f.ess_threshold
            ));
        }
        if f.newton_max_iter == 0 || !(f.newton_tol.is_finite() && f.newton_tol > 0.0) {
            return Err("filter.newton_max_iter must be >= 1 and filter.newton_tol > 0".into());
        }
        self.model().map(|_| ())
    }
}

/// The scenario.
pub struct VictoriaParkScenario;

/// The built system: the run (shared by plant, filter and metrics).
#[derive(Clone, Debug)]
pub struct VictoriaParkSystem {
    pub params: VictoriaParkParams,
    pub run: Arc<data::Run>,
    pub start: Pose,
    pub model: SlamModel,
}

impl VictoriaParkSystem {
    /// A system on a run already read (tests, other front ends).
    pub fn from_run(params: VictoriaParkParams, run: data::Run) -> Result<Self, String> {
        params.validate()?;
        if run.steps() == 0 || run.gps.is_empty() {
            return Err("the run needs two odometry samples and a GPS fix".into());
        }
        let start = run.start(params.start_heading_deg.to_radians());
        Ok(Self {
            model: params.model()?,
            params,
            run: Arc::new(run),
            start,
        })
    }

    /// The SLAM backends' settings.
    pub fn slam_config(&self) -> LiveSlamConfig {
        let f = &self.params.filter;
        LiveSlamConfig {
            model: self.model,
            particles: f.particles,
            ess_threshold: f.ess_threshold,
            newton: NewtonSettings {
                max_iter: f.newton_max_iter,
                tol: f.newton_tol,
            },
            time_scale: self.params.speedup,
        }
    }
}

impl Scenario for VictoriaParkScenario {
    type Params = VictoriaParkParams;
    const NAME: &'static str = "victoria-park";
    const SUMMARY: &'static str =
        "the real Victoria Park run (ACFR) streamed live: odometry + tree-feature channels, implicit SLAM / FastSLAM 2.0 / EKF-SLAM, error vs GPS";
    const CONFIG: &'static str = include_str!("../../../../../configs/victoria-park.toml");
    fn defaults(_ctx: &BuildContext) -> VictoriaParkParams {
        VictoriaParkParams::default()
    }
    fn params_schema() -> Option<schemars::Schema> {
        crate::inline_schema::<VictoriaParkParams>()
    }
    fn build(p: VictoriaParkParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        p.validate()?;
        let dir = victoria::resolve_dir((!p.data_dir.is_empty()).then_some(p.data_dir.as_str()));
        let run = data::load(&dir, p.end_time_s, p.max_range, p.gps_max_speed)?;
        Ok(Box::new(VictoriaParkSystem::from_run(p, run)?))
    }
}

impl System for VictoriaParkSystem {
    fn dynamics(&self) -> Dynamics {
        let m = &self.model;
        let (sr, sb) = (m.laser.var_range.sqrt(), m.laser.var_bearing.sqrt());
        let dt = 0.025;
        Dynamics::Discrete(DiscreteSpec {
            name: "victoria-park",
            dims: Dims {
                state: live_slam::POSE,
                noise: live_slam::POSE,
                obs: live_slam::LASER0 + 3 * live_slam::PER_SAMPLE,
                control: 1,
            },
            // The control noise P read as one 25 ms step's σ; the diameter
            // is a tag the filters do not read.
            obs_std: vec![
                (m.motion.p[0] / dt).sqrt(),
                (m.motion.p[1] / dt).sqrt(),
                sr,
                sb,
                0.0,
                sr,
                sb,
                0.0,
            ],
        })
    }
    fn position_axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn initial_state(&self) -> Vec<f64> {
        vec![self.start[0], self.start[1], self.start[2]]
    }
    /// The start pose. The SLAM filters start at the prior's mean (the
    /// map's frame is fixed by it); the spread, small, is not used.
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (self.initial_state(), vec![1e-3, 1e-3, 1e-4])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![
            SensorChannel {
                id: ODOMETRY,
                name: "odometry",
                components: vec![0, 1],
            },
            SensorChannel {
                id: LASER,
                name: "laser",
                components: (live_slam::LASER0..live_slam::LASER0 + 3 * live_slam::PER_SAMPLE)
                    .collect(),
            },
        ]
    }
    fn plant(&self, _x0: &[f64], _seed: u64, _max_dt: f64) -> Result<Box<dyn Plant>, String> {
        Ok(Box::new(plant::VictoriaParkPlant::new(
            self.run.clone(),
            self.params.speedup,
        )?))
    }
    fn filter_backends(&self) -> Vec<&'static str> {
        live_slam::BACKENDS.to_vec()
    }
    fn filter_backend(
        &self,
        name: &str,
        ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        live_slam::LiveSlam::new(name, &self.slam_config(), self.dims(), ctx)
            .map(|r| r.map(|f| Box::new(f) as Box<dyn BayesFilter>))
    }
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        Some(Box::new(metrics::VictoriaParkMetrics::new(self)))
    }
}

#[cfg(test)]
mod tests;
