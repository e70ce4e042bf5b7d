//! Continuous–discrete extended Kalman filter (Jazwinski 1970, §8; the EKF
//! baseline of paper 001 §4 and thesis §3.4) on any [`SdeJacobians`] model.
//!
//! Between measurements the mean and covariance follow the linearised
//! moment equations, integrated with classical RK4 in ⌈Δ/max_dt⌉ equal
//! substeps (global error O(h⁴) on smooth models):
//!
//! ```text
//! dm/dt = f(m, u)
//! dP/dt = A P + P Aᵀ + F Fᵀ,     A = ∂f/∂x (m, u),  F = F(m)
//! ```
//!
//! At a measurement: linearise g at m (H = ∂g/∂x), innovation r = y ⊖ g(m)
//! from the model's `obs_residual` (angles wrap), and the Joseph-form update
//! on the masked components (see `gauss`). A prediction or update whose
//! result is not finite or not positive semi-definite is refused with
//! [`FilterError::Numerical`] and the previous belief is kept.

use super::build::{self, BuildError, ConfigError};
use super::gauss::{self, Mat, ObsMat};
use super::gauss_state::{gaussian_info, measurement_std, predict_span, reset_or_keep, GaussState};
use super::{check_measurement, BayesFilter, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::model::{Dims, Measurement, SdeJacobians};
use crate::{MAX_NOISE, MAX_OBS, MAX_STATE};
use serde::{Deserialize, Serialize};

/// Settings of the EKF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct EkfConfig {
    /// Largest RK4 substep of the moment equations (seconds).
    pub max_dt: f64,
}

impl Default for EkfConfig {
    fn default() -> Self {
        Self { max_dt: 0.01 }
    }
}

impl EkfConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        build::positive("max_dt", self.max_dt)
    }

    /// An EKF at time `t0` with prior N(mean, cov) — the construction
    /// shared by every filter config. Besides [`Self::validate`], the RK4
    /// substep is checked against the model ([`build::StepRule::Rk4`]):
    /// `max_dt · ρ ≤` [`build::RK4_RATE_STEP`], ρ the 99th-percentile
    /// spectral radius of
    /// the drift Jacobian over trajectories from the prior
    /// ([`crate::model::scale::probe`], a fixed seed).
    pub fn build<M: SdeJacobians>(
        &self,
        model: M,
        prior: &Gaussian,
        t0: f64,
    ) -> Result<Ekf<M>, BuildError> {
        self.validate()?;
        let dims = model.dims();
        build::check_dims(dims)?;
        gauss::check_prior(prior, dims.state)?;
        build::check_step(
            &model,
            prior,
            "max_dt",
            self.max_dt,
            build::StepRule::Rk4,
            0,
        )?;
        Ekf::unchecked(model, self, prior, t0)
    }
}

/// Continuous–discrete EKF.
#[derive(Clone, Debug)]
pub struct Ekf<M: SdeJacobians> {
    model: M,
    cfg: EkfConfig,
    dims: Dims,
    s: GaussState,
}

impl<M: SdeJacobians> Ekf<M> {
    /// An EKF at time `t0` with prior N(mean, cov): the same as
    /// [`EkfConfig::build`], step check included.
    pub fn new(model: M, cfg: &EkfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        cfg.build(model, prior, t0)
    }

    fn unchecked(model: M, cfg: &EkfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        cfg.validate()?;
        let dims = model.dims();
        build::check_dims(dims)?;
        Ok(Self {
            s: GaussState::new(dims.state, prior, t0)?,
            model,
            cfg: cfg.clone(),
            dims,
        })
    }

    /// Restart from `prior` at `t`, rejecting an invalid prior.
    pub fn try_reset(&mut self, t: f64, prior: &Gaussian) -> Result<(), FilterError> {
        self.s.try_reset(t, prior)
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Right-hand side of the moment equations at (m, P).
    fn moments_rhs(&self, m: &[f64], p: &[f64], u: &[f64], dm: &mut [f64], dp: &mut [f64]) {
        let Dims {
            state: d, noise: k, ..
        } = self.dims;
        let mut a: Mat = [0.0; MAX_STATE * MAX_STATE];
        let mut big_f = [0.0; MAX_STATE * MAX_NOISE];
        self.model.drift(m, u, dm);
        self.model.drift_jacobian(m, u, &mut a[..d * d]);
        self.model.diffusion(m, &mut big_f[..d * k]);
        let mut ap: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul(&a, d, d, p, d, &mut ap);
        let mut q: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul_bt(&big_f, d, k, &big_f, d, &mut q);
        for c in 0..d {
            for r in 0..d {
                dp[r + c * d] = ap[r + c * d] + ap[c + r * d] + q[r + c * d];
            }
        }
    }
}

impl<M: SdeJacobians> BayesFilter for Ekf<M> {
    fn name(&self) -> &'static str {
        "ekf"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.s.t
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        reset_or_keep("ekf", self.try_reset(t, prior));
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        let Some(dur) = predict_span(self.s.t, t, u, self.dims)? else {
            return Ok(());
        };
        let d = self.dims.state;
        let steps = (dur / self.cfg.max_dt).ceil().max(1.0);
        let h = dur / steps;
        let mut m = self.s.mean;
        let mut p = self.s.cov;
        gauss::rk4_moments(d, &mut m, &mut p, h, steps as usize, |ms, ps, dm, dp| {
            self.moments_rhs(ms, ps, u, dm, dp)
        });
        if gauss::asymmetry(&p, d) > 1e-6 {
            return Err(FilterError::Numerical("predicted covariance lost symmetry"));
        }
        gauss::symmetrize(&mut p, d);
        self.s
            .accept(&m, &p, "predicted covariance is not positive semi-definite")?;
        self.s.t = t;
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let Dims {
            state: d, obs: m, ..
        } = self.dims;
        let mut yhat = [0.0; MAX_OBS];
        let mut r = [0.0; MAX_OBS];
        let mut h: ObsMat = [0.0; MAX_OBS * MAX_STATE];
        self.model.obs_mean(&self.s.mean[..d], &mut yhat[..m]);
        self.model
            .obs_residual(&meas.y[..m], &yhat[..m], &mut r[..m]);
        self.model.obs_jacobian(&self.s.mean[..d], &mut h[..m * d]);
        let std = measurement_std(&self.model, meas, m);
        let log_evidence = self.s.joseph_update(m, &h, &r, &std, meas.mask)?;
        Ok(gaussian_info(log_evidence))
    }

    fn belief(&self) -> Gaussian {
        self.s.belief()
    }
}

/// Shared test scaffolding for the Gaussian filters (EKF, UKF).
#[cfg(test)]
pub(crate) mod testutil {
    use crate::belief::Gaussian;
    use crate::filter::kalman::testmodels::oscillator;
    use crate::filter::kalman::Kalman;
    use crate::filter::BayesFilter;
    use crate::model::ship::{Ship, ShipParams};
    use crate::model::{Bounds, Dims, Measurement, ObsMask, SdeJacobians, SdeModel};
    use crate::rng;

    /// Oscillator data: (time, control, measurement), seeded.
    pub fn oscillator_data(steps: usize, dt: f64, seed: u64) -> Vec<(f64, f64, [f64; 2])> {
        let model = oscillator([0.2, 0.3]);
        let mut rng = rng::stream(seed, 99);
        let mut x = [1.0, 0.0];
        (1..=steps)
            .map(|k| {
                let u = (0.7 * k as f64 * dt).sin();
                crate::model::discrete::em_integrate(&model, &mut x, &[u], dt, 1e-4, &mut rng);
                let mut y = [0.0; 2];
                crate::model::simulate_observation(&model, &x, &mut rng, &mut y);
                (k as f64 * dt, u, y)
            })
            .collect()
    }

    pub fn prior() -> Gaussian {
        let mut p = Gaussian::diagonal(&[0.8, 0.2], &[0.5, 0.4]);
        p.set_cov(0, 1, 0.05);
        p.set_cov(1, 0, 0.05);
        p
    }

    /// Run a filter over oscillator data (every third measurement masked to
    /// component 0 with a σ override), returning the beliefs.
    pub fn run<F: BayesFilter>(f: &mut F, data: &[(f64, f64, [f64; 2])]) -> Vec<Gaussian> {
        let override_std = [0.5, 0.3];
        data.iter()
            .enumerate()
            .map(|(k, (t, u, y))| {
                f.predict(*t, &[*u]).unwrap();
                let meas = if k % 3 == 2 {
                    Measurement {
                        y,
                        mask: ObsMask(0b01),
                        std: Some(&override_std),
                    }
                } else {
                    Measurement::full(y)
                };
                f.update(&meas).unwrap();
                f.belief()
            })
            .collect()
    }

    /// Largest difference of means and covariances, relative to the
    /// Kalman filter's posterior scale.
    pub fn max_rel_diff(a: &[Gaussian], b: &[Gaussian]) -> f64 {
        let mut worst: f64 = 0.0;
        for (x, y) in a.iter().zip(b) {
            let d = x.dim;
            for i in 0..d {
                let s = y.cov_at(i, i).sqrt();
                worst = worst.max((x.mean[i] - y.mean[i]).abs() / s);
                for j in 0..d {
                    let sc = (y.cov_at(i, i) * y.cov_at(j, j)).sqrt();
                    worst = worst.max((x.cov_at(i, j) - y.cov_at(i, j)).abs() / sc);
                }
            }
        }
        worst
    }

    pub fn kalman_reference(data: &[(f64, f64, [f64; 2])]) -> Vec<Gaussian> {
        let mut kf = Kalman::new(oscillator([0.2, 0.3]), &prior(), 0.0).unwrap();
        run(&mut kf, data)
    }

    /// (time, true state, measurement).
    pub type ShipSample = (f64, [f64; 4], [f64; 2]);

    /// Start of the ship test runs; it reaches the wall after ≈ 2.5 s.
    pub const SHIP_X0: [f64; 4] = [2.0, -1.0, 2.5, 1.0];

    /// A ship run at 100 Hz with the paper's noise (σ = 0.3 for range and
    /// bearing): (time, truth, measurement).
    pub fn ship_data(seconds: f64, seed: u64) -> (Ship, Vec<ShipSample>) {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let mut rng = rng::stream(seed, 7);
        let mut x = SHIP_X0;
        let steps = (seconds / 0.01).round() as usize;
        let data = (1..=steps)
            .map(|k| {
                crate::model::discrete::em_integrate(
                    &ship,
                    &mut x,
                    &[0.0, 0.0],
                    0.01,
                    1e-3,
                    &mut rng,
                );
                let mut y = [0.0; 2];
                crate::model::simulate_observation(&ship, &x, &mut rng, &mut y);
                (k as f64 * 0.01, x, y)
            })
            .collect();
        (ship, data)
    }

    /// Position RMSE of a filter on ship data, and that of inverting each raw
    /// measurement (the no-filter reference).
    pub fn ship_rmse<F: BayesFilter>(f: &mut F, data: &[ShipSample]) -> (f64, f64) {
        let (mut se, mut se_raw) = (0.0, 0.0);
        for (t, x, y) in data {
            f.predict(*t, &[0.0, 0.0]).unwrap();
            f.update(&Measurement::full(y)).unwrap();
            let b = f.belief();
            se += (b.mean[0] - x[0]).powi(2) + (b.mean[1] - x[1]).powi(2);
            let (px, py) = (y[0] * y[1].cos(), y[0] * y[1].sin());
            se_raw += (px - x[0]).powi(2) + (py - x[1]).powi(2);
        }
        let n = data.len() as f64;
        ((se / n).sqrt(), (se_raw / n).sqrt())
    }

    /// The oscillator, except that its drift is NaN beyond x₀ = 3: a model
    /// that breaks numerically, to check that filters refuse the step.
    pub struct Breaks(pub crate::model::linear::LinearSde);
    impl SdeModel for Breaks {
        fn name(&self) -> &str {
            "breaks"
        }
        fn dims(&self) -> Dims {
            self.0.dims()
        }
        fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
            self.0.drift(x, u, f);
            if x[0] > 3.0 {
                f[0] = f64::NAN;
            }
        }
        fn diffusion(&self, x: &[f64], f: &mut [f64]) {
            self.0.diffusion(x, f)
        }
        fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
            self.0.obs_mean(x, g)
        }
        fn obs_std(&self, s: &mut [f64]) {
            self.0.obs_std(s)
        }
        fn bounds(&self) -> &Bounds {
            self.0.bounds()
        }
    }
    impl SdeJacobians for Breaks {}
}

#[cfg(test)]
mod tests {
    use super::testutil::*;
    use super::*;
    use crate::filter::kalman::testmodels::oscillator;

    fn ekf_run(max_dt: f64, data: &[(f64, f64, [f64; 2])]) -> Vec<Gaussian> {
        let cfg = EkfConfig { max_dt };
        let mut ekf = Ekf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        run(&mut ekf, data)
    }

    /// On a linear model the EKF's moment equations are exact, so it differs
    /// from the Kalman filter only by the RK4 error: O(h⁴), i.e. below
    /// (h‖A‖)⁴ relative to the posterior scale, and ≈ 16× smaller at h/2.
    #[test]
    fn matches_the_kalman_filter_on_a_linear_model() {
        let data = oscillator_data(40, 0.05, 4);
        let exact = kalman_reference(&data);
        let a_norm = 2.2; // ‖A‖₂ of the oscillator (≈ 2.16)
        let mut prev = None;
        for h in [0.025, 0.0125, 0.00625] {
            let err = max_rel_diff(&ekf_run(h, &data), &exact);
            let bound = (h * a_norm).powi(4);
            assert!(err < bound, "h = {h}: error {err} above {bound}");
            if let Some(p) = prev {
                let ratio: f64 = p / err;
                assert!(ratio > 10.0, "RK4 order lost: ratio {ratio}");
            }
            prev = Some(err);
        }
    }

    #[test]
    fn tracks_the_ship_better_than_inverting_measurements() {
        let (ship, data) = ship_data(8.0, 1);
        let prior = Gaussian::diagonal(&SHIP_X0, &[0.3, 0.3, 0.3, 0.3]);
        let mut ekf = Ekf::new(ship, &EkfConfig::default(), &prior, 0.0).unwrap();
        let (rmse, raw) = ship_rmse(&mut ekf, &data);
        // The run reaches the wall (ρ ≥ 9) and is pushed back.
        let rho_max = data
            .iter()
            .map(|(_, x, _)| x[0].hypot(x[1]))
            .fold(0.0, f64::max);
        assert!(rho_max > 9.0, "{rho_max}");
        assert!(rmse < 0.5 * raw, "EKF {rmse} vs raw {raw}");
    }

    #[test]
    fn numerical_failure_keeps_the_belief() {
        let model = Breaks(oscillator([0.2, 0.3]));
        let prior = Gaussian::diagonal(&[2.9, 5.0], &[0.1, 0.1]);
        let mut ekf = Ekf::new(model, &EkfConfig::default(), &prior, 0.0).unwrap();
        let e = ekf.predict(1.0, &[0.0]);
        assert!(matches!(e, Err(FilterError::Numerical(_))), "{e:?}");
        assert_eq!(ekf.belief(), prior);
        assert_eq!(ekf.time(), 0.0);
    }

    #[test]
    fn config_rejects_bad_values() {
        assert!(toml::from_str::<EkfConfig>("max_dt = 0.001").is_ok());
        assert!(toml::from_str::<EkfConfig>("dt = 0.001").is_err());
        let bad = EkfConfig { max_dt: -1.0 };
        assert_eq!(bad.validate().unwrap_err().key, "max_dt");
        assert!(Ekf::new(oscillator([0.2, 0.3]), &bad, &prior(), 0.0).is_err());
    }
}
