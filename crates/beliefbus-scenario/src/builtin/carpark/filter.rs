//! Backends `implicit-mcl` and `mcl`: the localization crate's implicit
//! MCL and standard MCL ([`Localizer`]) behind the pipeline's
//! [`BayesFilter`], on the car park's map, vehicle and noise.
//!
//! The filter runs on the odometry: each odometry sample n at time t_n is
//! one MCL step with u_n = (v_c, α), v_c = L v_l / (L − H tan α), over
//! δ_n = t_n − t_{n−1} (the Ute's δ per step, so late or lost samples
//! lengthen the step instead of shifting the clock; the first step is one
//! sensor period from the prior):
//!
//! ```text
//! no scan pending:  X_n^j = f_n^j + ΔB^j, weights unchanged       (prediction)
//! scan pending:     the localizer's laser step with the scan        (implicit or standard)
//! estimate:         Σ_j W^j X^j; covariance Σ_j W^j (X^j − X̂)(X^j − X̂)ᵀ, heading residuals wrapped
//! ```
//!
//! A laser sample only adds its features to the pending scan (the belief
//! is unchanged); the scan is applied with the next odometry sample, which
//! the plant publishes at the scan's time right after it. Features of an
//! older scan still pending when a newer scan's arrive were never applied
//! (their odometry sample was lost) and are dropped.
//!
//! The published ESS is that of the laser step's weights before any
//! resampling; a prediction keeps the weights and reports their ESS. The
//! published heading is the weighted circular mean moved to the branch of
//! the particles' (unwrapped) headings, so it stays continuous like the
//! truth's. Per-sample σ overrides are ignored: the laser's Σ₂ is the
//! map's model. Buffers are sized at construction; a step allocates
//! nothing.

use super::encoding::{read_slot, SlotError, PER_SAMPLE};
use super::{CarparkSystem, STATE};
use crate::backends::FilterContext;
use crate::rng::SimRng;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{
    check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo,
};
use beliefbus_core::model::{Dims, Measurement};
use beliefbus_localization::carpark::CarPark;
use beliefbus_localization::geometry::{wrap_angle, Pose};
use beliefbus_localization::laser::Observation;
use beliefbus_localization::mcl::implicit::ImplicitMcl;
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::mcl::standard::StandardMcl;
use beliefbus_localization::mcl::{LaserStep, Localizer};
use beliefbus_localization::vehicle::{Control, StepNoise, Ute};
use beliefbus_localization::LocalizationError;
use std::f64::consts::PI;
use std::sync::Arc;

/// Features a pending scan holds at most (a scan has at most 6; more come
/// only from a publisher outside the ABI's burst limit).
const SCAN_CAP: usize = 64;

/// Either localizer, without boxing.
#[derive(Debug)]
enum Mcl {
    Implicit(ImplicitMcl),
    Standard(StandardMcl),
}

impl Mcl {
    fn get(&mut self) -> &mut dyn Localizer {
        match self {
            Mcl::Implicit(f) => f,
            Mcl::Standard(f) => f,
        }
    }
    fn get_ref(&self) -> &dyn Localizer {
        match self {
            Mcl::Implicit(f) => f,
            Mcl::Standard(f) => f,
        }
    }
}

/// The backend.
#[derive(Debug)]
pub struct MclFilter {
    name: &'static str,
    cp: Arc<CarPark>,
    mcl: Mcl,
    rng: SimRng,
    seed: u64,
    resets: u64,
    dims: Dims,
    sample_dt: f64,
    /// Time of the last `predict` (the observation's time).
    time: f64,
    /// Time of the last odometry step (None: none yet).
    odo_time: Option<f64>,
    /// The pending scan and its measurement time.
    scan: Vec<Observation>,
    scan_time: f64,
    /// Odometry steps so far (the localizer's step index).
    steps: usize,
    ess: f64,
    belief: Gaussian,
}

fn mcl_error(e: LocalizationError) -> FilterError {
    match e {
        LocalizationError::Degenerate { .. } => FilterError::Degenerate,
        _ => FilterError::Numerical("car park MCL"),
    }
}

impl MclFilter {
    /// From `[carpark.filter]`; implicit MCL when `implicit`, else
    /// standard MCL. The stream is `ctx.seed`.
    pub fn new(sys: &CarparkSystem, ctx: &FilterContext, implicit: bool) -> Result<Self, String> {
        let p = &sys.params.filter;
        let mcl = if implicit {
            let newton = NewtonSettings {
                max_iter: p.newton_max_iter,
                tol: p.newton_tol,
            };
            Mcl::Implicit(
                ImplicitMcl::new(p.particles, p.ess_threshold, newton)
                    .map_err(|e| e.to_string())?,
            )
        } else {
            Mcl::Standard(
                StandardMcl::new(p.particles, p.ess_threshold).map_err(|e| e.to_string())?,
            )
        };
        let mut f = Self {
            name: if implicit {
                super::IMPLICIT
            } else {
                super::STANDARD
            },
            cp: sys.carpark.clone(),
            mcl,
            rng: crate::rng::stream(ctx.seed, 0),
            seed: ctx.seed,
            resets: 0,
            dims: crate::System::dims(sys),
            sample_dt: ctx.sample_dt,
            time: ctx.t0,
            odo_time: None,
            scan: Vec::with_capacity(SCAN_CAP),
            scan_time: f64::NEG_INFINITY,
            steps: 0,
            ess: p.particles as f64,
            belief: Gaussian::zeros(STATE),
        };
        if ctx.start.dim != STATE || !ctx.start.is_finite() {
            return Err(format!("the prior needs {STATE} finite dimensions"));
        }
        f.init(&ctx.start);
        Ok(f)
    }

    /// Particles from N(mean, diag(cov)), equal weights.
    fn init(&mut self, prior: &Gaussian) {
        let mean = Pose::new(prior.mean[0], prior.mean[1], prior.mean[2]);
        let std = Pose::new(
            prior.cov_at(0, 0).max(0.0).sqrt(),
            prior.cov_at(1, 1).max(0.0).sqrt(),
            prior.cov_at(2, 2).max(0.0).sqrt(),
        );
        self.mcl
            .get()
            .particles_mut()
            .init(&mean, &std, &mut self.rng);
        self.ess = self.mcl.get_ref().particles().len() as f64;
        self.odo_time = None;
        self.scan.clear();
        self.scan_time = f64::NEG_INFINITY;
        self.steps = 0;
        self.summarise();
    }

    /// The weighted mean and covariance into `self.belief`.
    fn summarise(&mut self) {
        let set = self.mcl.get_ref().particles();
        let est = set.estimate();
        // The circular mean on the particles' branch.
        let lift = est[2] + 2.0 * PI * ((set.x[0][2] - est[2]) / (2.0 * PI)).round();
        let mut g = Gaussian::zeros(STATE);
        g.mean[0] = est[0];
        g.mean[1] = est[1];
        g.mean[2] = lift;
        let mut c = [[0.0; STATE]; STATE];
        for (x, &w) in set.x.iter().zip(&set.w) {
            let d = [x[0] - est[0], x[1] - est[1], wrap_angle(x[2] - est[2])];
            for a in 0..STATE {
                for b in 0..=a {
                    c[a][b] += w * d[a] * d[b];
                }
            }
        }
        for a in 0..STATE {
            for b in 0..=a {
                g.set_cov(a, b, c[a][b]);
                g.set_cov(b, a, c[a][b]);
            }
        }
        self.belief = g;
    }

    /// The ESS of the current weights.
    fn current_ess(&self) -> f64 {
        1.0 / self
            .mcl
            .get_ref()
            .particles()
            .w
            .iter()
            .map(|w| w * w)
            .sum::<f64>()
    }

    /// One odometry step: u_n over (t_{n−1}, t_n], with the pending scan.
    fn odometry(&mut self, v_wheel: f64, alpha: f64) -> Result<UpdateInfo, FilterError> {
        let cp = self.cp.clone();
        let v = cp
            .ute
            .centre_speed(v_wheel, alpha)
            .map_err(|_| FilterError::Numerical("steering outside the vehicle's range"))?;
        let u = Control { v, alpha };
        let dt = match self.odo_time {
            None => self.sample_dt,
            Some(t) => self.time - t,
        };
        self.odo_time = Some(self.time);
        if dt <= 0.0 {
            // A repeated time: nothing moves.
            return Ok(self.no_step());
        }
        let ute = Ute { dt, ..cp.ute };
        let noise = StepNoise::new(&ute, u, &cp.motion).map_err(mcl_error)?;
        self.steps += 1;
        let set = self.mcl.get_ref().particles();
        let (before_sum, before_rs) = (set.ess_fraction_sum, set.resamplings);
        let m = set.len() as f64;
        let info = if self.scan.is_empty() {
            self.mcl.get().predict(&ute, u, &noise, &mut self.rng);
            self.no_step()
        } else {
            let step = LaserStep {
                ute: &ute,
                u,
                noise: &noise,
                obs: &self.scan,
                map: &cp.landmarks,
                laser: &cp.laser,
                step: self.steps,
            };
            let r = match &mut self.mcl {
                Mcl::Implicit(f) => f.update(&step, &mut self.rng),
                Mcl::Standard(f) => f.update(&step, &mut self.rng),
            };
            self.scan.clear();
            r.map_err(mcl_error)?;
            let set = self.mcl.get_ref().particles();
            // The step's ESS before resampling: its share of the running sum.
            self.ess = (set.ess_fraction_sum - before_sum) * m;
            UpdateInfo {
                log_evidence: f64::NAN,
                ess: self.ess,
                resampled: set.resamplings > before_rs,
            }
        };
        self.summarise();
        Ok(info)
    }

    /// What a step that changes no weight reports.
    fn no_step(&mut self) -> UpdateInfo {
        self.ess = self.current_ess();
        UpdateInfo {
            log_evidence: f64::NAN,
            ess: self.ess,
            resampled: false,
        }
    }

    /// A laser sample: its features join the pending scan.
    fn laser(&mut self, y: &[f64]) -> Result<UpdateInfo, FilterError> {
        if self.time > self.scan_time {
            // A newer scan: one still pending lost its odometry sample.
            self.scan.clear();
            self.scan_time = self.time;
        }
        let map_len = self.cp.landmarks.len();
        for i in 0..PER_SAMPLE {
            match read_slot(y, i, map_len) {
                Ok(Some(o)) if self.scan.len() < SCAN_CAP => self.scan.push(o),
                Ok(_) => {}
                Err(SlotError::Landmark(_)) => {
                    return Err(FilterError::Dimension {
                        what: "laser landmark index (the map's size is expected above it)",
                        got: 0,
                        expected: map_len,
                    })
                }
                Err(SlotError::Value) => {
                    return Err(FilterError::NonFinite("laser range or bearing"))
                }
            }
        }
        Ok(UpdateInfo {
            log_evidence: f64::NAN,
            ess: self.ess,
            resampled: false,
        })
    }

    /// The localizer (tests, diagnostics).
    pub fn localizer(&self) -> &dyn Localizer {
        self.mcl.get_ref()
    }

    /// Features of the scan waiting for its odometry sample.
    pub fn pending_features(&self) -> usize {
        self.scan.len()
    }
}

impl BayesFilter for MclFilter {
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
        if prior.dim == STATE && prior.is_finite() {
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
        } else if (super::encoding::LASER0..super::encoding::OBS).all(|i| m.contains(i)) {
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
