//! The live car-park localization scenario `carpark` (paper 003 §4.1 and
//! appendix): the synthetic car park of `beliefbus_localization::carpark`
//! — the Ute driven by a stretch of the Victoria Park wheel speed and
//! steering, a seeded landmark layout along its path, a range/bearing
//! laser in a 15 m forward half circle with seeded gaps — played live
//! through the sensor ABI on **two channels**:
//!
//! - channel 0, `odometry`, 40 Hz (the recorded odometry times): wheel
//!   speed v_l (m/s, the rear-left encoder) and steering α (rad), the
//!   observation components 0, 1;
//! - channel 1, `laser`, at the recorded scan times (≈ 4.7 Hz, 213–215 ms,
//!   no sample in the gaps nor for a scan that sees no landmark): up to two
//!   features per sample, components 2–7 = (r₁, b₁, m₁, r₂, b₂, m₂) with
//!   range (m), bearing (rad, laser frame, π/2 ahead) and the index m of
//!   the landmark in the map (the association MCL is given); an empty
//!   second slot is (0, 0, −1). The samples of one scan share its
//!   measurement time; ingest admits at most 3 samples at one instant, so
//!   a scan carries at most 6 features (the plant keeps the nearest,
//!   [`CarparkParams::max_features`]) ([`encoding`]).
//!
//! A scan belongs to the odometry step at or after its time (as in the
//! offline data set): the plant publishes it at that step's time, before
//! the step's odometry sample, and the filter applies it with that sample
//! (one laser step n = motion with u_n plus the scan; paper 003 eq. 19 and
//! §4.1). Backends, selected by name:
//! - `filter.backend = "implicit-mcl"`: implicit MCL ([`filter`]);
//! - `filter.backend = "mcl"`: standard MCL, the same models and data;
//!
//! both on the map known to the filter;
//! - `filter.backend = "implicit-slam"`, `"implicit-refine-slam"`, `"fastslam2"`, `"ekf-slam"`: SLAM,
//!   the map unknown, the landmark index ignored ([`super::live_slam`]; the
//!   belief carries the map's landmark count after the pose);
//!
//! and optionally
//! - `control.backend = "pure-pursuit"`: steer along the data set's path
//!   from the belief ([`control`]), or `control.backend = "path-mppi"`: the
//!   same path followed by MPPI on the car's kinematics ([`mppi`]); the
//!   plant then drives itself with the recorded wheel speed and the
//!   commanded steering ([`plant`]).
//!
//! Estimation only by default (`control.backend = "none"`: the vehicle
//! replays the recorded drive; the control is the steering α). The report's
//! `scenario_metrics.carpark` ([`metrics`]) gives the pose error against
//! dead reckoning, the ESS, the time per update and the per-channel counts.
//!
//! State: the laser pose (x, y, β) in the frame of the drive's start (the
//! heading not wrapped, so it stays continuous along the drive). The data
//! set is drawn from `data_seed` when the system is built: every process
//! builds the same one, and the filter knows its landmark map.

pub mod control;
pub mod encoding;
pub mod filter;
pub mod metrics;
pub mod mppi;
pub mod plant;

use super::live_slam;
use crate::backends::{ControlContext, FilterContext};
use crate::metrics::RunMetrics;
use crate::model::Dims;
use crate::{BuildContext, DiscreteSpec, Dynamics, Plant, Scenario, SensorChannel, System};
use beliefbus_core::control::Controller;
use beliefbus_core::filter::BayesFilter;
use beliefbus_localization::carpark::{CarPark, CarParkConfig};
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::slam::assoc::AssocConfig;
use beliefbus_localization::slam::SlamModel;
use beliefbus_localization::victoria;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Filter backend: implicit MCL.
pub const IMPLICIT: &str = "implicit-mcl";
/// Filter backend: standard MCL.
pub const STANDARD: &str = "mcl";
/// Controller: pure pursuit along the path.
pub const PURE_PURSUIT: &str = "pure-pursuit";
/// Controller: MPPI along the path.
pub const MPPI: &str = "path-mppi";
/// Channel ids.
pub const ODOMETRY: u32 = 0;
pub const LASER: u32 = 1;
/// State dimension (x, y, β).
pub const STATE: usize = 3;

/// `[carpark]`: the data set and the filters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CarparkParams {
    /// Victoria Park folder (odometry.csv, laser_times.csv), read in place;
    /// empty: $BELIEFBUS_VICTORIA_PARK, else ../shared/data/victoria-park.
    pub data_dir: String,
    /// Seed of the data set (true path noise, landmarks, gaps, laser noise).
    pub data_seed: u64,
    /// Start of the odometry stretch on the data set's clock (s).
    pub start_time_s: f64,
    /// Length of the stretch (s); the plant idles after it.
    pub duration_s: f64,
    /// Scale of the true path's noise vs the filters' model.
    pub truth_noise: f64,
    /// Laser radius (m).
    pub max_range: f64,
    /// Arc length between landmarks along the path (m).
    pub landmark_spacing: f64,
    /// One laser gap per window of this length (s); 0: none.
    pub gap_every_s: f64,
    /// Length of each gap (s).
    pub gap_len_s: f64,
    /// Features per scan the plant publishes (the nearest), 1..=6.
    pub max_features: usize,
    /// `[carpark.filter]`: backends `implicit-mcl` and `mcl`.
    pub filter: CarparkFilterParams,
    /// `[carpark.control]`: controller `pure-pursuit`.
    pub control: CarparkControlParams,
}

/// `[carpark.control]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CarparkControlParams {
    /// Look-ahead distance ℓ along the path (m).
    pub lookahead_m: f64,
    /// Steering limit (rad); the plant clamps to it too.
    pub max_steering: f64,
    /// `path-mppi`: sampled steering sequences K.
    pub mppi_samples: usize,
    /// `path-mppi`: horizon steps T.
    pub mppi_horizon_steps: usize,
    /// `path-mppi`: rollout step Δ (s).
    pub mppi_dt: f64,
    /// `path-mppi`: temperature λ (cost units: m² s of squared cross-track
    /// distance).
    pub mppi_temperature: f64,
    /// `path-mppi`: σ of the steering noise (rad).
    pub mppi_noise_std: f64,
    /// `path-mppi`: weight r of r α² per second.
    pub mppi_control_weight: f64,
}

/// `[carpark.filter]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CarparkFilterParams {
    /// Samples M.
    pub particles: usize,
    /// Resample systematically when ESS < this fraction of M.
    pub ess_threshold: f64,
    /// Implicit MCL: at most this many Newton steps per particle.
    pub newton_max_iter: usize,
    /// Implicit MCL: stop when the Newton decrement falls below this.
    pub newton_tol: f64,
}

impl Default for CarparkParams {
    /// The `mcl` experiment's defaults (Table 7 vehicle and noise), over a
    /// longer stretch so that live runs of minutes have data.
    fn default() -> Self {
        let c = CarParkConfig::default();
        Self {
            data_dir: String::new(),
            data_seed: 1,
            start_time_s: c.start_time,
            duration_s: 600.0,
            truth_noise: c.truth_noise,
            max_range: c.max_range,
            landmark_spacing: c.landmark_spacing,
            gap_every_s: c.gap_every,
            gap_len_s: c.gap_len,
            max_features: encoding::MAX_FEATURES,
            filter: CarparkFilterParams {
                particles: 100,
                ess_threshold: 0.5,
                newton_max_iter: 20,
                newton_tol: 1e-3,
            },
            control: CarparkControlParams {
                lookahead_m: 8.0,
                max_steering: 0.6,
                mppi_samples: 128,
                mppi_horizon_steps: 10,
                mppi_dt: 0.1,
                mppi_temperature: 0.1,
                mppi_noise_std: 0.1,
                mppi_control_weight: 0.01,
            },
        }
    }
}

impl CarparkParams {
    /// The data set's settings.
    pub fn carpark_config(&self) -> CarParkConfig {
        CarParkConfig {
            start_time: self.start_time_s,
            duration: self.duration_s,
            truth_noise: self.truth_noise,
            max_range: self.max_range,
            landmark_spacing: self.landmark_spacing,
            gap_every: self.gap_every_s,
            gap_len: self.gap_len_s,
            ..CarParkConfig::default()
        }
    }

    fn validate(&self) -> Result<(), String> {
        if !(1..=encoding::MAX_FEATURES).contains(&self.max_features) {
            return Err(format!(
                "max_features must be in 1..={}, got {}",
                encoding::MAX_FEATURES,
                self.max_features
            ));
        }
        let f = &self.filter;
        if !(1..=100_000).contains(&f.particles) {
            return Err(format!(
                "filter.particles must be in 1..=100000, got {}",
                f.particles
            ));
        }
        if !(0.0..=1.0).contains(&f.ess_threshold) {
            return Err(format!(
                "filter.ess_threshold must be in [0, 1], got {}",
                f.ess_threshold
            ));
        }
        let c = &self.control;
        let lookahead_ok = c.lookahead_m.is_finite() && c.lookahead_m > 0.0;
        let steering_ok = c.max_steering > 0.0 && c.max_steering < 1.2;
        if !(lookahead_ok && steering_ok) {
            return Err(format!(
                "control.lookahead_m must be > 0 and control.max_steering in (0, 1.2) rad, got {} and {}",
                c.lookahead_m, c.max_steering
            ));
        }
        if f.newton_max_iter == 0 || !(f.newton_tol.is_finite() && f.newton_tol > 0.0) {
            return Err("filter.newton_max_iter must be >= 1 and filter.newton_tol > 0".into());
        }
        Ok(())
    }
}

/// The scenario.
pub struct CarparkScenario;

/// The built system: the data set (shared by the plant, the filters and
/// the metrics) and the settings.
#[derive(Clone, Debug)]
pub struct CarparkSystem {
    pub params: CarparkParams,
    pub carpark: Arc<CarPark>,
    /// The sensor period (s): the odometry's nominal step.
    pub sample_dt: f64,
}

impl CarparkSystem {
    /// A system on a data set already drawn (tests, other front ends).
    pub fn from_carpark(
        params: CarparkParams,
        carpark: CarPark,
        sample_dt: f64,
    ) -> Result<Self, String> {
        params.validate()?;
        if !(sample_dt.is_finite() && sample_dt > 0.0) {
            return Err(format!(
                "the sample period must be positive, got {sample_dt}"
            ));
        }
        if carpark.steps() == 0 {
            return Err("the car park has no odometry step".into());
        }
        Ok(Self {
            params,
            carpark: Arc::new(carpark),
            sample_dt,
        })
    }
}

impl Scenario for CarparkScenario {
    type Params = CarparkParams;
    const NAME: &'static str = "carpark";
    const SUMMARY: &'static str =
        "synthetic car park on Victoria Park odometry (paper 003 sec. 4.1): odometry + laser channels, implicit/standard MCL, optional pure pursuit";
    const CONFIG: &'static str = include_str!("../../../../../configs/carpark.toml");
    fn defaults(_ctx: &BuildContext) -> CarparkParams {
        CarparkParams::default()
    }
    fn params_schema() -> Option<schemars::Schema> {
        crate::inline_schema::<CarparkParams>()
    }
    fn build(p: CarparkParams, ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        p.validate()?;
        let dir = victoria::resolve_dir((!p.data_dir.is_empty()).then_some(p.data_dir.as_str()));
        let rec = victoria::load(&dir)
            .map_err(|e| format!("{e} (or set carpark.data_dir in the config)"))?;
        let mut rng = crate::rng::stream(p.data_seed, 0);
        let cp =
            CarPark::generate(&rec, &p.carpark_config(), &mut rng).map_err(|e| e.to_string())?;
        Ok(Box::new(CarparkSystem::from_carpark(p, cp, ctx.sample_dt)?))
    }
}

impl CarparkSystem {
    /// The SLAM backends' settings: the data set's vehicle and noise, the
    /// shared association gates, `[carpark.filter]`'s samples and Newton
    /// settings.
    pub fn slam_config(&self) -> live_slam::LiveSlamConfig {
        let cp = &self.carpark;
        let f = &self.params.filter;
        live_slam::LiveSlamConfig {
            model: SlamModel {
                ute: cp.ute,
                motion: cp.motion,
                laser: cp.laser,
                assoc: AssocConfig::default(),
                max_range: self.params.max_range,
            },
            particles: f.particles,
            ess_threshold: f.ess_threshold,
            newton: NewtonSettings {
                max_iter: f.newton_max_iter,
                tol: f.newton_tol,
            },
            time_scale: 1.0,
        }
    }
}

impl System for CarparkSystem {
    fn dynamics(&self) -> Dynamics {
        let cp = &self.carpark;
        let (sr, sb) = (cp.laser.var_range.sqrt(), cp.laser.var_bearing.sqrt());
        Dynamics::Discrete(DiscreteSpec {
            name: "carpark",
            dims: Dims {
                state: STATE,
                noise: STATE,
                obs: encoding::OBS,
                control: 1,
            },
            // The control noise P read as one step's σ; the landmark index
            // is exact.
            obs_std: vec![
                (cp.motion.p[0] / cp.ute.dt).sqrt(),
                (cp.motion.p[1] / cp.ute.dt).sqrt(),
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
        let x = self.carpark.truth[0];
        vec![x[0], x[1], x[2]]
    }
    /// The `mcl` experiment's prior: the true start spread by 0.3 m and
    /// 0.02 rad.
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (self.initial_state(), vec![0.3, 0.3, 0.02])
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
                components: (2..encoding::OBS).collect(),
            },
        ]
    }
    fn plant(&self, x0: &[f64], seed: u64, _max_dt: f64) -> Result<Box<dyn Plant>, String> {
        Ok(Box::new(plant::CarparkPlant::new(self, x0, seed)?))
    }
    fn filter_backends(&self) -> Vec<&'static str> {
        let mut v = vec![IMPLICIT, STANDARD];
        v.extend(live_slam::BACKENDS);
        v
    }
    fn filter_backend(
        &self,
        name: &str,
        ctx: &FilterContext,
    ) -> Option<Result<Box<dyn BayesFilter>, String>> {
        let implicit = match name {
            IMPLICIT => true,
            STANDARD => false,
            _ => {
                return live_slam::LiveSlam::new(name, &self.slam_config(), self.dims(), ctx)
                    .map(|r| r.map(|f| Box::new(f) as Box<dyn BayesFilter>))
            }
        };
        Some(
            filter::MclFilter::new(self, ctx, implicit)
                .map(|f| Box::new(f) as Box<dyn BayesFilter>),
        )
    }
    fn controller_backends(&self) -> Vec<&'static str> {
        vec![PURE_PURSUIT, MPPI]
    }
    fn controller(
        &self,
        name: &str,
        ctx: &ControlContext,
    ) -> Option<Result<Box<dyn Controller>, String>> {
        match name {
            PURE_PURSUIT => {
                Some(control::PurePursuit::new(self).map(|c| Box::new(c) as Box<dyn Controller>))
            }
            MPPI => Some(
                mppi::MppiFollower::new(self, ctx.seed).map(|c| Box::new(c) as Box<dyn Controller>),
            ),
            _ => None,
        }
    }
    fn run_metrics(&self) -> Option<Box<dyn RunMetrics>> {
        Some(Box::new(metrics::CarparkMetrics::new(self)))
    }
}

#[cfg(test)]
mod tests;
