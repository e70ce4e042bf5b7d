//! Live SLAM backends: the localization crate's online SLAM filters
//! (paper 003 §4.2; [`beliefbus_localization::slam`]) behind the
//! pipeline's [`BayesFilter`], for the scenarios whose observation vector
//! is laid out as the car park's (`carpark`, `victoria-park`):
//!
//! ```text
//! component   0     1     2   3   4    5   6   7
//! odometry    v_l   α
//! laser                   r₁  b₁  c₁   r₂  b₂  c₂      (c = −1: empty slot)
//! ```
//!
//! with range r (m), bearing b (rad, laser frame, π/2 ahead) and a tag c
//! the SLAM filters do not read (the car park's landmark index, Victoria
//! Park's trunk diameter): SLAM associates every return itself, by the one
//! maximum-likelihood rule all four filters share.
//!
//! - `implicit-slam`: [`ImplicitSlam`] (per-particle pose and sampled map;
//!   a new feature from the joint 5-D F^j, a re-observed one by the implicit
//!   MCL step);
//! - `implicit-refine-slam`: [`ImplicitRefineSlam`] (as `implicit-slam`, but
//!   a re-observed feature is drawn again jointly with the pose, its earlier
//!   sightings entering exactly: the map keeps improving; docs/slam.md);
//! - `fastslam2`: [`FastSlam`] 2.0 (per-landmark EKFs, observation in the
//!   proposal);
//! - `ekf-slam`: [`EkfSlam`], the joint-state EKF.
//!
//! One odometry sample n at pipeline time t_n is one SLAM step with
//! u_n = (v_c, α), v_c = L v_l / (L − H tan α), over the recorded interval
//! δ_n = (t_n − t_{n−1}) × `time_scale` (a plant that streams a recording
//! faster than it was recorded divides its clock by the speed-up; the
//! filter multiplies it back), taking every return that arrived since the
//! previous odometry sample (a scan is published just before the odometry
//! sample it belongs to). The first odometry sample is one sensor period
//! (× `time_scale`) from the prior. Returns beyond the model's `max_range`
//! are dropped (the same cut as the offline experiments).
//!
//! The belief is the pose estimate (the particles' weighted mean or the
//! EKF's mean) with its covariance (the particles' weighted scatter, heading
//! residuals wrapped; the EKF's pose block), the heading lifted to the
//! branch of the previous estimate so it stays continuous; and one
//! auxiliary component after the pose, [`MAP_COMPONENT`]: the number of
//! landmarks in the filter's map (the heaviest particle's), with variance
//! 0. The map itself stays inside the filter stage; the count lets the run
//! metrics report its size through the fixed belief layout. The system's
//! state is the pose alone (the pipeline scores the first 3 components).
//! The ESS is that of the step's weights before resampling (1 for the EKF).
//! Buffers are sized at construction; a step allocates only where a filter
//! grows its map.

use crate::backends::FilterContext;
use crate::rng::SimRng;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{
    check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo,
};
use beliefbus_core::model::{Dims, Measurement};
use beliefbus_localization::geometry::{wrap_angle, Pose};
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::slam::assoc::RangeBearing;
use beliefbus_localization::slam::ekf::EkfSlam;
use beliefbus_localization::slam::fastslam::{FastSlam, Version};
use beliefbus_localization::slam::implicit::ImplicitSlam;
use beliefbus_localization::slam::implicit_refine::ImplicitRefineSlam;
use beliefbus_localization::slam::particles::SlamParticles;
use beliefbus_localization::slam::{SlamFilter, SlamModel};
use beliefbus_localization::vehicle::Control;
use beliefbus_localization::LocalizationError;
use std::f64::consts::PI;

/// Backend names.
pub const IMPLICIT_SLAM: &str = "implicit-slam";
pub const IMPLICIT_REFINE_SLAM: &str = "implicit-refine-slam";
pub const FASTSLAM2: &str = "fastslam2";
pub const EKF_SLAM: &str = "ekf-slam";
/// Every SLAM backend.
pub const BACKENDS: [&str; 4] = [IMPLICIT_SLAM, IMPLICIT_REFINE_SLAM, FASTSLAM2, EKF_SLAM];
/// The pose (x, y, β).
pub const POSE: usize = 3;
/// The belief component holding the map's landmark count.
pub const MAP_COMPONENT: usize = POSE;
/// First laser component and features per laser sample.
pub const LASER0: usize = 2;
pub const PER_SAMPLE: usize = 2;
/// The tag of an empty slot.
pub const EMPTY: f64 = -1.0;
/// Returns held between two odometry samples at most (more are dropped).
const PENDING_CAP: usize = 64;

/// What a backend is built from.
#[derive(Clone, Copy, Debug)]
pub struct LiveSlamConfig {
    pub model: SlamModel,
    /// Samples M (particle filters).
    pub particles: usize,
    /// Resample when ESS < this fraction of M.
    pub ess_threshold: f64,
    pub newton: NewtonSettings,
    /// Recorded seconds per pipeline second (the plant's speed-up).
    pub time_scale: f64,
}

/// The three filters, without boxing.
#[derive(Debug)]
enum Slam {
    Implicit(Box<ImplicitSlam>),
    Refine(Box<ImplicitRefineSlam>),
    Fast(Box<FastSlam>),
    Ekf(Box<EkfSlam>),
}

impl Slam {
    fn get(&mut self) -> &mut dyn SlamFilter {
        match self {
            Slam::Implicit(f) => f.as_mut(),
            Slam::Refine(f) => f.as_mut(),
            Slam::Fast(f) => f.as_mut(),
            Slam::Ekf(f) => f.as_mut(),
        }
    }
    fn get_ref(&self) -> &dyn SlamFilter {
        match self {
            Slam::Implicit(f) => f.as_ref(),
            Slam::Refine(f) => f.as_ref(),
            Slam::Fast(f) => f.as_ref(),
            Slam::Ekf(f) => f.as_ref(),
        }
    }
    /// Landmarks in the map estimate (no allocation).
    fn map_len(&self) -> usize {
        match self {
            Slam::Implicit(f) => f.set.maps[f.set.best()].len(),
            Slam::Refine(f) => f.set.maps[f.set.best()].len(),
            Slam::Fast(f) => f.set.maps[f.set.best()].len(),
            Slam::Ekf(f) => f.state.landmarks(),
        }
    }
    /// The pose covariance (row-major 3 × 3) about `mean`.
    fn pose_cov(&self, mean: &Pose) -> [[f64; POSE]; POSE] {
        // Between returns (the interval prior) each particle carries the
        // noise it has not drawn yet as a covariance C_i, so the pose
        // covariance is the mixture's: Σ_i w_i (d_i d_iᵀ + C_i).
        fn scatter<L: Clone>(set: &SlamParticles<L>, mean: &Pose) -> [[f64; POSE]; POSE] {
            let mut c = [[0.0; POSE]; POSE];
            for ((x, &w), acc) in set.x.iter().zip(&set.w).zip(&set.acc) {
                let d = [x[0] - mean[0], x[1] - mean[1], wrap_angle(x[2] - mean[2])];
                for a in 0..POSE {
                    for b in 0..POSE {
                        c[a][b] += w * (d[a] * d[b] + acc[(a, b)]);
                    }
                }
            }
            c
        }
        match self {
            Slam::Implicit(f) => scatter(&f.set, mean),
            Slam::Refine(f) => scatter(&f.set, mean),
            Slam::Fast(f) => scatter(&f.set, mean),
            Slam::Ekf(f) => {
                let p = f.state.pose_cov();
                let mut c = [[0.0; POSE]; POSE];
                for (a, row) in c.iter_mut().enumerate() {
                    for (b, v) in row.iter_mut().enumerate() {
                        *v = p[(a, b)];
                    }
                }
                c
            }
        }
    }
}

fn slam_error(e: LocalizationError) -> FilterError {
    match e {
        LocalizationError::Degenerate { .. } => FilterError::Degenerate,
        _ => FilterError::Numerical("live SLAM step"),
    }
}

/// The backend.
#[derive(Debug)]
pub struct LiveSlam {
    name: &'static str,
    slam: Slam,
    model: SlamModel,
    particles: usize,
    time_scale: f64,
    rng: SimRng,
    seed: u64,
    resets: u64,
    dims: Dims,
    sample_dt: f64,
    /// Time of the last `predict` (the observation's time).
    time: f64,
    /// Time of the last odometry step (None: none yet).
    odo_time: Option<f64>,
    /// Returns since the last odometry step.
    pending: Vec<RangeBearing>,
    dropped: u64,
    ess: f64,
    belief: Gaussian,
}

impl LiveSlam {
    /// Backend `name` (one of [`BACKENDS`]; `None` for another name) for a
    /// system of dimensions `dims`, started at `ctx.start`'s pose.
    pub fn new(
        name: &str,
        cfg: &LiveSlamConfig,
        dims: Dims,
        ctx: &FilterContext,
    ) -> Option<Result<Self, String>> {
        let slam = match name {
            IMPLICIT_SLAM => {
                ImplicitSlam::new(cfg.model, cfg.particles, cfg.ess_threshold, cfg.newton)
                    .map(|f| (IMPLICIT_SLAM, Slam::Implicit(Box::new(f))))
            }
            IMPLICIT_REFINE_SLAM => {
                ImplicitRefineSlam::new(cfg.model, cfg.particles, cfg.ess_threshold, cfg.newton)
                    .map(|f| (IMPLICIT_REFINE_SLAM, Slam::Refine(Box::new(f))))
            }
            FASTSLAM2 => FastSlam::new(cfg.model, Version::Two, cfg.particles, cfg.ess_threshold)
                .map(|f| (FASTSLAM2, Slam::Fast(Box::new(f)))),
            EKF_SLAM => EkfSlam::new(cfg.model).map(|f| (EKF_SLAM, Slam::Ekf(Box::new(f)))),
            _ => return None,
        };
        Some(Self::build(slam.map_err(|e| e.to_string()), cfg, dims, ctx))
    }

    fn build(
        slam: Result<(&'static str, Slam), String>,
        cfg: &LiveSlamConfig,
        dims: Dims,
        ctx: &FilterContext,
    ) -> Result<Self, String> {
        let (name, mut slam) = slam?;
        // The particle filters draw the noise of the odometry steps between
        // two scans at the next scan, from a proposal that sees its returns
        // (slam::particles, "interval prior"), as the offline experiments
        // do by default; the EKF has no such setting.
        slam.get().set_interval_prior(true);
        if !(cfg.time_scale.is_finite() && cfg.time_scale > 0.0) {
            return Err(format!(
                "the time scale must be > 0, got {}",
                cfg.time_scale
            ));
        }
        if dims.state != POSE || dims.obs < LASER0 + 3 * PER_SAMPLE {
            return Err(format!(
                "live SLAM needs a {POSE}-D pose state and {} observation components",
                LASER0 + 3 * PER_SAMPLE
            ));
        }
        if ctx.start.dim < POSE || !ctx.start.is_finite() {
            return Err(format!("the prior needs {POSE} finite dimensions"));
        }
        let mut f = Self {
            name,
            slam,
            model: cfg.model,
            particles: cfg.particles,
            time_scale: cfg.time_scale,
            rng: crate::rng::stream(ctx.seed, 0),
            seed: ctx.seed,
            resets: 0,
            dims,
            sample_dt: ctx.sample_dt,
            time: ctx.t0,
            odo_time: None,
            pending: Vec::with_capacity(PENDING_CAP),
            dropped: 0,
            ess: 1.0,
            belief: Gaussian::zeros(POSE + 1),
        };
        f.init(&ctx.start);
        Ok(f)
    }

    /// Start at the prior's mean pose with an empty map.
    fn init(&mut self, prior: &Gaussian) {
        let start = Pose::new(prior.mean[0], prior.mean[1], prior.mean[2]);
        self.slam.get().reset(&start);
        self.odo_time = None;
        self.pending.clear();
        self.ess = self.full_ess();
        self.summarise(&start);
    }

    /// The ESS of equal weights (M, or 1 for the EKF).
    fn full_ess(&self) -> f64 {
        match self.slam {
            Slam::Ekf(_) => 1.0,
            _ => self.particles as f64,
        }
    }

    /// The estimate, its covariance and the map size into `self.belief`.
    fn summarise(&mut self, est: &Pose) {
        let prev = self.belief.mean[2];
        let lift = est[2] + 2.0 * PI * ((prev - est[2]) / (2.0 * PI)).round();
        let c = self.slam.pose_cov(est);
        let mut g = Gaussian::zeros(POSE + 1);
        g.mean[0] = est[0];
        g.mean[1] = est[1];
        g.mean[2] = lift;
        g.mean[MAP_COMPONENT] = self.slam.map_len() as f64;
        for (a, row) in c.iter().enumerate() {
            for (b, &v) in row.iter().enumerate() {
                g.set_cov(a, b, v);
            }
        }
        self.belief = g;
    }

    /// One odometry step with the pending returns.
    fn odometry(&mut self, v_wheel: f64, alpha: f64) -> Result<UpdateInfo, FilterError> {
        let v = self
            .model
            .ute
            .centre_speed(v_wheel, alpha)
            .map_err(|_| FilterError::Numerical("steering outside the vehicle's range"))?;
        let dt = match self.odo_time {
            None => self.sample_dt,
            Some(t) => self.time - t,
        } * self.time_scale;
        self.odo_time = Some(self.time);
        if dt <= 0.0 {
            // A repeated time: nothing moves; the returns wait.
            return Ok(self.info(false));
        }
        let before = self.slam.get_ref().stats();
        let est = self
            .slam
            .get()
            .step(Control { v, alpha }, dt, &self.pending, &mut self.rng);
        let had_returns = !self.pending.is_empty();
        self.pending.clear();
        let est = est.map_err(slam_error)?;
        let after = self.slam.get_ref().stats();
        self.ess = match self.slam {
            Slam::Ekf(_) => 1.0,
            _ if after.updates > before.updates => {
                (after.ess_fraction_sum - before.ess_fraction_sum) * self.particles as f64
            }
            // A prediction keeps the weights: their ESS.
            _ => self.current_ess(),
        };
        self.summarise(&est);
        Ok(self.info(had_returns && after.resamplings > before.resamplings))
    }

    fn current_ess(&self) -> f64 {
        let w = match &self.slam {
            Slam::Implicit(f) => &f.set.w,
            Slam::Refine(f) => &f.set.w,
            Slam::Fast(f) => &f.set.w,
            Slam::Ekf(_) => return 1.0,
        };
        1.0 / w.iter().map(|w| w * w).sum::<f64>()
    }

    fn info(&self, resampled: bool) -> UpdateInfo {
        UpdateInfo {
            log_evidence: f64::NAN,
            ess: self.ess,
            resampled,
        }
    }

    /// A laser sample: its returns wait for the next odometry sample.
    fn laser(&mut self, y: &[f64]) -> Result<UpdateInfo, FilterError> {
        for i in 0..PER_SAMPLE {
            let k = LASER0 + 3 * i;
            let (r, b, tag) = (y[k], y[k + 1], y[k + 2]);
            if tag == EMPTY {
                continue;
            }
            if !(r.is_finite() && r > 0.0 && b.is_finite()) {
                return Err(FilterError::NonFinite("laser range or bearing"));
            }
            if r > self.model.max_range {
                continue;
            }
            if self.pending.len() < PENDING_CAP {
                self.pending.push(RangeBearing {
                    range: r,
                    bearing: b,
                });
            } else {
                self.dropped += 1;
            }
        }
        Ok(self.info(false))
    }

    /// Landmarks in the map estimate.
    pub fn map_len(&self) -> usize {
        self.slam.map_len()
    }

    /// Returns waiting for their odometry sample.
    pub fn pending_returns(&self) -> usize {
        self.pending.len()
    }

    /// Returns dropped because more than the buffer's capacity arrived
    /// between two odometry samples.
    pub fn dropped_returns(&self) -> u64 {
        self.dropped
    }

    /// The wrapped filter (tests, diagnostics).
    pub fn slam(&self) -> &dyn SlamFilter {
        self.slam.get_ref()
    }
}

impl BayesFilter for LiveSlam {
    fn name(&self) -> &'static str {
        self.name
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.time
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        // A fresh stream per reset keeps runs reproducible.
        self.resets += 1;
        self.rng = crate::rng::stream(self.seed, self.resets);
        self.time = t;
        if prior.dim >= POSE && prior.is_finite() {
            self.init(prior);
        }
    }
    /// Only the clock: the motion comes with the odometry.
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.time, t, u, self.dims)?;
        self.time = t;
        Ok(())
    }
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let m = meas.mask;
        if m.contains(0) && m.contains(1) {
            self.odometry(meas.y[0], meas.y[1])
        } else if (LASER0..LASER0 + 3 * PER_SAMPLE).all(|i| m.contains(i)) {
            self.laser(meas.y)
        } else {
            Err(FilterError::Dimension {
                what: "observation mask (odometry needs components 0-1, laser 2-7)",
                got: m.count(),
                expected: 2,
            })
        }
    }
    fn belief(&self) -> Gaussian {
        self.belief
    }
}
