//! Continuous–discrete unscented Kalman filter (Julier & Uhlmann 1997; Wan &
//! van der Merwe 2000 weights; continuous–discrete form after Särkkä 2007),
//! a baseline beside the EKF and the bootstrap PF.
//!
//! Sigma points of N(m, P) in dimension n, with λ = α²(n + κ) − n:
//!
//! ```text
//! χ₀ = m,  χ_{±i} = m ± √(n+λ) L_i   (L Lᵀ = P, columns L_i)
//! W_m⁰ = λ/(n+λ),  W_c⁰ = W_m⁰ + 1 − α² + β,  W_m^{±i} = W_c^{±i} = 1/(2(n+λ))
//! ```
//!
//! Prediction over Δ, in ⌈Δ/max_dt⌉ substeps of length h, each a Strang
//! splitting of drift and additive process noise Q = F(m)F(m)ᵀ:
//!
//! ```text
//! P ← P + ½ Q h;   χ_i ← RK4 flow of dx/dt = f(x, u) over h;
//! m ← Σ W_m χ_i,   P ← Σ W_c (χ_i − m)(χ_i − m)ᵀ;   P ← P + ½ Q h
//! ```
//!
//! (second order in h for the noise term; on a linear model the sigma-point
//! moments are exact, so the UKF equals the Kalman filter up to O(h²)).
//!
//! Update on the masked components, with angles handled by the model's
//! `obs_residual`: γ_i = g(χ_i), the predicted observation is the *wrapped*
//! weighted mean ŷ = γ₀ + Σ W_m (γ_i ⊖ γ₀), then
//!
//! ```text
//! S = Σ W_c (γ_i ⊖ ŷ)(γ_i ⊖ ŷ)ᵀ + R,   C = Σ W_c (χ_i − m)(γ_i ⊖ ŷ)ᵀ,
//! K = C S⁻¹,   m ← m + K (y ⊖ ŷ),   P ← P − K S Kᵀ
//! ```
//!
//! A step whose result is not finite or not positive semi-definite is
//! refused with [`FilterError::Numerical`]; the previous belief is kept.

use super::build::{self, BuildError, ConfigError};
use super::gauss::{self, Mat, ObsMat};
use super::gauss_state::{
    gain_and_evidence, gain_step, gaussian_info, masked_rows, measurement_std, predict_span,
    reset_or_keep, GaussState,
};
use super::{check_measurement, BayesFilter, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::math::linalg;
use crate::model::{Dims, Measurement, SdeModel};
use crate::{MAX_NOISE, MAX_OBS, MAX_STATE};
use serde::{Deserialize, Serialize};

/// Most sigma points: 2·MAX_STATE + 1.
const MAX_SIGMA: usize = 2 * MAX_STATE + 1;

/// Settings of the UKF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct UkfConfig {
    /// Largest prediction substep (seconds).
    pub max_dt: f64,
    /// Sigma-point spread α (α = 1 with κ = 0 puts W_m⁰ = 0 and keeps every
    /// covariance weight non-negative).
    pub alpha: f64,
    /// Prior-knowledge parameter β (2 is optimal for Gaussian priors).
    pub beta: f64,
    /// Secondary scaling κ.
    pub kappa: f64,
}

impl Default for UkfConfig {
    fn default() -> Self {
        Self {
            max_dt: 0.01,
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
        }
    }
}

impl UkfConfig {
    /// Check every field for a state of dimension `n`.
    pub fn validate(&self, n: usize) -> Result<(), ConfigError> {
        build::positive("max_dt", self.max_dt)?;
        build::positive("alpha", self.alpha)?;
        if !self.beta.is_finite() {
            return Err(ConfigError::new("beta", "must be finite"));
        }
        if !(self.kappa.is_finite() && n as f64 + self.kappa > 0.0) {
            return Err(ConfigError::new(
                "kappa",
                format!("n + kappa must be positive (n = {n}), got {}", self.kappa),
            ));
        }
        Ok(())
    }

    /// A UKF at time `t0` with prior N(mean, cov) — the construction
    /// shared by every filter config. Besides [`Self::validate`], the
    /// prediction substep is checked against the model
    /// ([`build::StepRule::Rk4`]): `max_dt · ρ ≤` [`build::RK4_RATE_STEP`],
    /// ρ the 99th-percentile spectral radius of
    /// the drift Jacobian over trajectories from the prior
    /// ([`crate::model::scale::probe`], a fixed seed).
    pub fn build<M: SdeModel>(
        &self,
        model: M,
        prior: &Gaussian,
        t0: f64,
    ) -> Result<Ukf<M>, BuildError> {
        let dims = model.dims();
        build::check_dims(dims)?;
        self.validate(dims.state)?;
        gauss::check_prior(prior, dims.state)?;
        build::check_step(
            &model,
            prior,
            "max_dt",
            self.max_dt,
            build::StepRule::Rk4,
            0,
        )?;
        Ukf::unchecked(model, self, prior, t0)
    }
}

/// Sigma-point weights and scale.
#[derive(Clone, Copy, Debug)]
struct Weights {
    wm0: f64,
    wc0: f64,
    wi: f64,
    gamma: f64,
}

impl Weights {
    fn new(cfg: &UkfConfig, n: usize) -> Self {
        let nf = n as f64;
        let a2 = cfg.alpha * cfg.alpha;
        let n_lambda = a2 * (nf + cfg.kappa); // n + λ
        let wm0 = 1.0 - nf / n_lambda; // λ/(n+λ)
        Self {
            wm0,
            wc0: wm0 + 1.0 - a2 + cfg.beta,
            wi: 0.5 / n_lambda,
            gamma: n_lambda.sqrt(),
        }
    }
    fn wm(&self, i: usize) -> f64 {
        if i == 0 {
            self.wm0
        } else {
            self.wi
        }
    }
    fn wc(&self, i: usize) -> f64 {
        if i == 0 {
            self.wc0
        } else {
            self.wi
        }
    }
}

/// Sigma points, point-major: chi[i·n .. (i+1)·n].
type Sigma = [f64; MAX_SIGMA * MAX_STATE];

/// Continuous–discrete UKF.
#[derive(Clone, Debug)]
pub struct Ukf<M: SdeModel> {
    model: M,
    cfg: UkfConfig,
    dims: Dims,
    w: Weights,
    s: GaussState,
}

impl<M: SdeModel> Ukf<M> {
    /// A UKF at time `t0` with prior N(mean, cov): the same as
    /// [`UkfConfig::build`], step check included.
    pub fn new(model: M, cfg: &UkfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        cfg.build(model, prior, t0)
    }

    fn unchecked(model: M, cfg: &UkfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        let dims = model.dims();
        build::check_dims(dims)?;
        cfg.validate(dims.state)?;
        Ok(Self {
            s: GaussState::new(dims.state, prior, t0)?,
            w: Weights::new(cfg, dims.state),
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

    fn n_sigma(&self) -> usize {
        2 * self.dims.state + 1
    }

    /// Sigma points of N(m, P) into `chi`.
    fn sigma_points(&self, m: &[f64], p: &[f64], chi: &mut Sigma) -> Result<(), FilterError> {
        let n = self.dims.state;
        let mut l: Mat = [0.0; MAX_STATE * MAX_STATE];
        l[..n * n].copy_from_slice(&p[..n * n]);
        if !linalg::cholesky_psd(&mut l, n) {
            return Err(FilterError::Numerical(
                "covariance is not positive semi-definite",
            ));
        }
        chi[..n].copy_from_slice(&m[..n]);
        for j in 0..n {
            for r in 0..n {
                let s = self.w.gamma * l[r + j * n];
                chi[(1 + j) * n + r] = m[r] + s;
                chi[(1 + n + j) * n + r] = m[r] - s;
            }
        }
        Ok(())
    }

    /// Weighted mean and covariance of point-major `pts` (count × n).
    fn moments(&self, pts: &Sigma, count: usize, m: &mut [f64], p: &mut [f64]) {
        let n = self.dims.state;
        m[..n].fill(0.0);
        for i in 0..count {
            let wm = self.w.wm(i);
            for r in 0..n {
                m[r] += wm * pts[i * n + r];
            }
        }
        p[..n * n].fill(0.0);
        for i in 0..count {
            let wc = self.w.wc(i);
            let mut e = [0.0; MAX_STATE];
            for r in 0..n {
                e[r] = pts[i * n + r] - m[r];
            }
            for c in 0..n {
                for r in 0..n {
                    p[r + c * n] += wc * e[r] * e[c];
                }
            }
        }
    }

    /// Add ½ F(m)F(m)ᵀ h to P.
    fn add_half_noise(&self, m: &[f64], p: &mut [f64], h: f64) {
        let Dims {
            state: n, noise: k, ..
        } = self.dims;
        let mut big_f = [0.0; MAX_STATE * MAX_NOISE];
        self.model.diffusion(&m[..n], &mut big_f[..n * k]);
        let mut q: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul_bt(&big_f, n, k, &big_f, n, &mut q);
        for i in 0..n * n {
            p[i] += 0.5 * h * q[i];
        }
    }

    /// RK4 flow of dx/dt = f(x, u) over h, in place.
    fn flow(&self, x: &mut [f64], u: &[f64], h: f64) {
        let n = x.len();
        let mut k = [[0.0; MAX_STATE]; 4];
        let mut xs = [0.0; MAX_STATE];
        self.model.drift(x, u, &mut k[0][..n]);
        for s in 1..4 {
            let c = if s == 3 { h } else { 0.5 * h };
            for i in 0..n {
                xs[i] = x[i] + c * k[s - 1][i];
            }
            let (_, rest) = k.split_at_mut(s);
            self.model.drift(&xs[..n], u, &mut rest[0][..n]);
        }
        for i in 0..n {
            x[i] += h / 6.0 * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
        }
    }
}

impl<M: SdeModel> BayesFilter for Ukf<M> {
    fn name(&self) -> &'static str {
        "ukf"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.s.t
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        reset_or_keep("ukf", self.try_reset(t, prior));
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        let Some(dur) = predict_span(self.s.t, t, u, self.dims)? else {
            return Ok(());
        };
        let n = self.dims.state;
        let count = self.n_sigma();
        let steps = (dur / self.cfg.max_dt).ceil().max(1.0);
        let h = dur / steps;
        let mut m = self.s.mean;
        let mut p = self.s.cov;
        let mut chi: Sigma = [0.0; MAX_SIGMA * MAX_STATE];
        for _ in 0..steps as usize {
            self.add_half_noise(&m, &mut p, h);
            self.sigma_points(&m, &p, &mut chi)?;
            for x in chi[..count * n].chunks_exact_mut(n) {
                self.flow(x, u, h);
            }
            self.moments(&chi, count, &mut m, &mut p);
            self.add_half_noise(&m, &mut p, h);
            gauss::symmetrize(&mut p, n);
        }
        self.s
            .accept(&m, &p, "predicted covariance is not positive semi-definite")?;
        self.s.t = t;
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let Dims {
            state: n, obs: mo, ..
        } = self.dims;
        let (idx, p) = masked_rows(meas.mask, mo);
        if p == 0 {
            return Ok(gaussian_info(0.0));
        }
        let count = self.n_sigma();
        let mut chi: Sigma = [0.0; MAX_SIGMA * MAX_STATE];
        self.sigma_points(&self.s.mean, &self.s.cov, &mut chi)?;
        // γ_i = g(χ_i), point-major count × mo.
        let mut gam = [0.0; MAX_SIGMA * MAX_OBS];
        for i in 0..count {
            self.model
                .obs_mean(&chi[i * n..(i + 1) * n], &mut gam[i * mo..(i + 1) * mo]);
        }
        // Wrapped weighted mean ŷ = γ₀ + Σ W_m (γ_i ⊖ γ₀).
        let mut yhat = [0.0; MAX_OBS];
        yhat[..mo].copy_from_slice(&gam[..mo]);
        let mut r = [0.0; MAX_OBS];
        for i in 1..count {
            self.model
                .obs_residual(&gam[i * mo..(i + 1) * mo], &gam[..mo], &mut r[..mo]);
            for j in 0..mo {
                yhat[j] += self.w.wm(i) * r[j];
            }
        }
        let std = measurement_std(&self.model, meas, mo);
        // S (p × p) and C (n × p) on the masked components.
        let mut s = [0.0; MAX_OBS * MAX_OBS];
        let mut c: ObsMat = [0.0; MAX_OBS * MAX_STATE];
        for i in 0..count {
            self.model
                .obs_residual(&gam[i * mo..(i + 1) * mo], &yhat[..mo], &mut r[..mo]);
            let wc = self.w.wc(i);
            for b in 0..p {
                let rb = wc * r[idx[b]];
                for a in 0..p {
                    s[a + b * p] += r[idx[a]] * rb;
                }
                for row in 0..n {
                    c[row + b * n] += (chi[i * n + row] - self.s.mean[row]) * rb;
                }
            }
        }
        for a in 0..p {
            s[a + a * p] += std[idx[a]] * std[idx[a]];
        }
        // Innovation y ⊖ ŷ on the mask.
        self.model
            .obs_residual(&meas.y[..mo], &yhat[..mo], &mut r[..mo]);
        let mut rs = [0.0; MAX_OBS];
        for a in 0..p {
            rs[a] = r[idx[a]];
        }
        let (kt, log_evidence) = gain_and_evidence(&mut s, &c, n, p, &rs)?;
        let m = gain_step(&self.s.mean, &kt, &rs, n, p);
        // P − K S Kᵀ = P − C Kᵀ.
        let mut pn = self.s.cov;
        for col in 0..n {
            for row in 0..n {
                let mut v = 0.0;
                for a in 0..p {
                    v += c[row + a * n] * kt[a + col * p];
                }
                pn[row + col * n] -= v;
            }
        }
        gauss::symmetrize(&mut pn, n);
        self.s
            .accept(&m, &pn, "updated covariance is not positive semi-definite")?;
        Ok(gaussian_info(log_evidence))
    }

    fn belief(&self) -> Gaussian {
        self.s.belief()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::ekf::testutil::*;
    use crate::filter::kalman::testmodels::oscillator;
    use crate::filter::kalman::Kalman;
    use crate::model::ship::{Ship, ShipParams};
    use crate::model::ObsMask;

    fn ukf_run(max_dt: f64, data: &[(f64, f64, [f64; 2])]) -> Vec<Gaussian> {
        let cfg = UkfConfig {
            max_dt,
            ..UkfConfig::default()
        };
        let mut ukf = Ukf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        run(&mut ukf, data)
    }

    /// On a linear model the sigma-point moments are exact, so the UKF
    /// differs from the Kalman filter only by the splitting of drift and
    /// noise: O(h²), below (h‖A‖)² relative to the posterior scale, and
    /// ≈ 4× smaller at h/2.
    #[test]
    fn matches_the_kalman_filter_on_a_linear_model() {
        let data = oscillator_data(40, 0.05, 4);
        let exact = kalman_reference(&data);
        let a_norm = 2.2;
        let mut prev = None;
        for h in [0.025, 0.0125, 0.00625] {
            let err = max_rel_diff(&ukf_run(h, &data), &exact);
            let bound = (h * a_norm).powi(2);
            assert!(err < bound, "h = {h}: error {err} above {bound}");
            if let Some(p) = prev {
                let ratio: f64 = p / err;
                assert!(ratio > 3.0, "second order lost: ratio {ratio}");
            }
            prev = Some(err);
        }
    }

    /// The update alone is exact on a linear observation (any α, β, κ).
    #[test]
    fn update_equals_the_kalman_update() {
        for (alpha, kappa) in [(1.0, 0.0), (0.5, 1.0), (1e-2, 0.0)] {
            let cfg = UkfConfig {
                alpha,
                kappa,
                ..UkfConfig::default()
            };
            let mut ukf = Ukf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
            let mut kf = Kalman::new(oscillator([0.2, 0.3]), &prior(), 0.0).unwrap();
            for meas in [
                Measurement::full(&[0.9, 0.1]),
                Measurement {
                    y: &[0.7, 9.0],
                    mask: ObsMask(0b01),
                    std: Some(&[0.05, 1.0]),
                },
            ] {
                let a = ukf.update(&meas).unwrap();
                let b = kf.update(&meas).unwrap();
                assert!((a.log_evidence - b.log_evidence).abs() < 1e-9);
            }
            assert!(max_rel_diff(&[ukf.belief()], &[kf.belief()]) < 1e-8);
        }
    }

    #[test]
    fn tracks_the_ship_better_than_inverting_measurements() {
        let (ship, data) = ship_data(8.0, 1);
        let prior = Gaussian::diagonal(&SHIP_X0, &[0.3, 0.3, 0.3, 0.3]);
        let mut ukf = Ukf::new(ship, &UkfConfig::default(), &prior, 0.0).unwrap();
        let (rmse, raw) = ship_rmse(&mut ukf, &data);
        assert!(rmse < 0.5 * raw, "UKF {rmse} vs raw {raw}");
    }

    /// A bearing-only update of a prior centred on the negative x-axis, whose
    /// sigma points straddle the ±π cut, equals (rotated) the same update of
    /// the problem rotated by −90°, where no angle wraps. Averaging raw
    /// angles there would put ŷ near 0 instead of π.
    #[test]
    fn bearing_mean_and_residuals_wrap() {
        let params = ShipParams {
            range_std: 0.05,
            bearing_std: 0.01,
            ..ShipParams::paper(0.01)
        };
        let std = [0.3, 0.3, 0.1, 0.1];
        let update = |mean: [f64; 4], bearing: f64| {
            let prior = Gaussian::diagonal(&mean, &std);
            let ship = Ship::new(params.clone()).unwrap();
            let mut ukf = Ukf::new(ship, &UkfConfig::default(), &prior, 0.0).unwrap();
            ukf.update(&Measurement {
                y: &[6.0, bearing],
                mask: ObsMask(0b10),
                std: None,
            })
            .unwrap();
            ukf.belief()
        };
        let pi = std::f64::consts::PI;
        let a = update([-6.0, 0.0, 0.0, 0.0], pi - 0.001);
        let b = update([0.0, 6.0, 0.0, 0.0], std::f64::consts::FRAC_PI_2 - 0.001);
        // (x, y) ↦ (y, −x): a's y is b's x, a's x is −b's y.
        assert!(
            (a.mean[1] - b.mean[0]).abs() < 1e-9,
            "{} vs {}",
            a.mean[1],
            b.mean[0]
        );
        assert!((a.mean[0] + b.mean[1]).abs() < 1e-9);
        assert!((a.cov_at(1, 1) - b.cov_at(0, 0)).abs() < 1e-9);
        assert!((a.cov_at(0, 0) - b.cov_at(1, 1)).abs() < 1e-9);
        // And the lateral update is the linearised one (≈ 0.0058).
        let lin = 0.006 * 0.05f64.powi(2) / (0.05f64.powi(2) + 0.01f64.powi(2));
        assert!((a.mean[1] - lin).abs() < 1e-3, "{}", a.mean[1]);
    }

    #[test]
    fn numerical_failure_keeps_the_belief() {
        let model = Breaks(oscillator([0.2, 0.3]));
        let prior = Gaussian::diagonal(&[2.9, 5.0], &[0.1, 0.1]);
        let mut ukf = Ukf::new(model, &UkfConfig::default(), &prior, 0.0).unwrap();
        let e = ukf.predict(1.0, &[0.0]);
        assert!(matches!(e, Err(FilterError::Numerical(_))), "{e:?}");
        assert_eq!(ukf.belief(), prior);
    }

    #[test]
    fn config_rejects_bad_values() {
        assert!(toml::from_str::<UkfConfig>("alpha = 0.5\nkappa = 1.0").is_ok());
        assert!(toml::from_str::<UkfConfig>("lambda = 1.0").is_err());
        let bad = UkfConfig {
            kappa: -2.0,
            ..UkfConfig::default()
        };
        assert_eq!(bad.validate(2).unwrap_err().key, "kappa");
        assert!(Ukf::new(oscillator([0.2, 0.3]), &bad, &prior(), 0.0).is_err());
    }
}
