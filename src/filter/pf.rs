//! Bootstrap particle filter (Gordon, Salmond & Smith 1993; the baseline of
//! paper 001 §4 and thesis §3.4) on any [`SdeModel`].
//!
//! Particles x⁽ⁱ⁾ with normalised log weights lw⁽ⁱ⁾:
//!
//! ```text
//! predict:  x⁽ⁱ⁾ ← Euler–Maruyama over Δ in ⌈Δ/max_dt⌉ equal substeps
//!           x ← x + f(x, u) h + F(x) √h ξ,  ξ ~ N(0, I)
//! update:   lw⁽ⁱ⁾ ← lw⁽ⁱ⁾ + log p(y | x⁽ⁱ⁾),  r = y ⊖ g(x) (model's obs_residual,
//!           so angles wrap), log p = Σ_{j ∈ mask} −½ (r_j/σ_j)² + const
//!           log p(y | y₁.ₖ₋₁) ≈ log Σ_i W⁽ⁱ⁾ p(y | x⁽ⁱ⁾)
//! resample: when ESS = 1/Σ W² < threshold · N (systematic by default),
//!           then every lw = −log N
//! belief:   m = Σ W x,  P = Σ W (x − m)(x − m)ᵀ
//! ```
//!
//! Everything is sized at construction: `predict` and `update` do not
//! allocate. A particle whose state becomes non-finite gets weight 0; if all
//! weights vanish the step is refused (`Degenerate` for an update,
//! `Numerical` for a prediction) and the previous particles are kept.

use super::build::{self, BuildError, ConfigError};
use super::gauss::{self, HALF_LOG_2PI};
use super::resample::{self, Scheme};
use super::{check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::model::{em_step, Dims, Measurement, SdeModel};
use crate::rng::{self, SimRng};
use crate::{MAX_OBS, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// RNG stream id of the particle filter (mixed with the config seed).
pub const PF_STREAM: u64 = 0x5046; // "PF"

/// Settings of the bootstrap particle filter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PfConfig {
    /// Number of particles N.
    pub particles: usize,
    /// Resample when ESS < resample_threshold · N (0: never, 1: always).
    pub resample_threshold: f64,
    /// Largest Euler–Maruyama substep (seconds). [`PfConfig::build`]
    /// refuses a step that is too coarse for the model (see
    /// [`build::em_step_bound`]); [`PfConfig::with_derived_step`] sets the
    /// largest acceptable one.
    pub max_dt: f64,
    /// Resampling scheme.
    pub resampling: Scheme,
    /// Seed of the filter's random stream.
    pub seed: u64,
}

impl Default for PfConfig {
    fn default() -> Self {
        Self {
            particles: 1000,
            resample_threshold: 0.5,
            max_dt: 0.01,
            resampling: Scheme::Systematic,
            seed: 0,
        }
    }
}

impl PfConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.particles == 0 {
            return Err(ConfigError::new("particles", "must be at least 1"));
        }
        if !(0.0..=1.0).contains(&self.resample_threshold) {
            return Err(ConfigError::new(
                "resample_threshold",
                format!("must be in [0, 1], got {}", self.resample_threshold),
            ));
        }
        build::positive("max_dt", self.max_dt)
    }

    /// A bootstrap PF of N particles drawn from `prior` at `t0` — the
    /// construction shared by every filter config (`XxxConfig { .. }.build`).
    ///
    /// Besides [`Self::validate`], the Euler–Maruyama step is checked
    /// against the model's time scales measured on trajectories from the
    /// prior ([`crate::model::scale::probe`] on a fixed stream, so the
    /// verdict depends on the model and prior only): `max_dt ≤` [`build::em_step_bound`] (the fastest rate
    /// resolved, and the drift error within the model's own diffusion) or
    /// a [`ConfigError`] on `max_dt` names the largest acceptable step.
    /// The check draws nothing from the filter's stream.
    pub fn build<M: SdeModel>(
        &self,
        model: M,
        prior: &Gaussian,
        t0: f64,
    ) -> Result<Pf<M>, BuildError> {
        self.validate()?;
        let dims = model.dims();
        build::check_dims(dims)?;
        gauss::check_prior(prior, dims.state)?;
        build::check_step(
            &model,
            prior,
            "max_dt",
            self.max_dt,
            build::StepRule::EulerMaruyama,
            0,
        )?;
        Pf::unchecked(model, self, prior, t0)
    }

    /// This config with `max_dt` lowered, if needed, to the largest step
    /// [`Self::build`] accepts for `model` started from `prior`.
    pub fn with_derived_step<M: SdeModel + ?Sized>(
        mut self,
        model: &M,
        prior: &Gaussian,
    ) -> Result<Self, FilterError> {
        let (max, _) = build::derived_step(model, prior, build::StepRule::EulerMaruyama, 0)?;
        self.max_dt = self.max_dt.min(max);
        Ok(self)
    }
}

/// Bootstrap particle filter.
pub struct Pf<M: SdeModel> {
    model: M,
    cfg: PfConfig,
    dims: Dims,
    t: f64,
    /// Particles, particle-major: x[i·d .. (i+1)·d].
    x: Vec<f64>,
    /// Second particle buffer (prediction output, resampling target).
    x_alt: Vec<f64>,
    /// Normalised log weights and the weights themselves.
    lw: Vec<f64>,
    w: Vec<f64>,
    /// Scratch log weights of an update in progress.
    lw_new: Vec<f64>,
    ancestors: Vec<usize>,
    ess: f64,
    rng: SimRng,
}

impl<M: SdeModel> Pf<M> {
    /// N particles drawn from the prior N(mean, cov) at time `t0`: the same
    /// as [`PfConfig::build`], step check included.
    pub fn new(model: M, cfg: &PfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        cfg.build(model, prior, t0)
    }

    fn unchecked(model: M, cfg: &PfConfig, prior: &Gaussian, t0: f64) -> Result<Self, BuildError> {
        cfg.validate()?;
        let dims = model.dims();
        build::check_dims(dims)?;
        gauss::check_prior(prior, dims.state)?;
        if !t0.is_finite() {
            return Err(FilterError::NonFinite("time").into());
        }
        let n = cfg.particles;
        let d = dims.state;
        let mut pf = Self {
            model,
            cfg: cfg.clone(),
            dims,
            t: t0,
            x: vec![0.0; n * d],
            x_alt: vec![0.0; n * d],
            lw: vec![0.0; n],
            w: vec![0.0; n],
            lw_new: vec![0.0; n],
            ancestors: vec![0; n],
            ess: n as f64,
            rng: rng::stream(cfg.seed, PF_STREAM),
        };
        pf.draw_prior(prior)?;
        Ok(pf)
    }

    fn draw_prior(&mut self, prior: &Gaussian) -> Result<(), FilterError> {
        let l = gauss::prior_factor(prior)?;
        let d = self.dims.state;
        let n = self.cfg.particles;
        for xi in self.x.chunks_exact_mut(d) {
            let mut xi_n = [0.0; MAX_STATE];
            for v in xi_n[..d].iter_mut() {
                *v = self.rng.sample(StandardNormal);
            }
            for r in 0..d {
                let mut s = prior.mean[r];
                for c in 0..=r {
                    s += l[r + c * d] * xi_n[c];
                }
                xi[r] = s;
            }
        }
        self.lw.fill(-(n as f64).ln());
        self.w.fill(1.0 / n as f64);
        self.ess = n as f64;
        Ok(())
    }

    /// Restart from `prior` at `t`, rejecting an invalid prior.
    pub fn try_reset(&mut self, t: f64, prior: &Gaussian) -> Result<(), FilterError> {
        if !t.is_finite() {
            return Err(FilterError::NonFinite("time"));
        }
        gauss::check_prior(prior, self.dims.state)?;
        self.draw_prior(prior)?;
        self.t = t;
        Ok(())
    }

    /// The particles, particle-major (`particles()[i*d..(i+1)*d]` is x⁽ⁱ⁾).
    pub fn particles(&self) -> &[f64] {
        &self.x
    }
    /// Normalised weights W⁽ⁱ⁾.
    pub fn weights(&self) -> &[f64] {
        &self.w
    }
    /// Effective sample size of the current weights.
    pub fn ess(&self) -> f64 {
        self.ess
    }
    /// The config the filter was built with.
    pub fn config(&self) -> &PfConfig {
        &self.cfg
    }
    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Resample unconditionally with the configured scheme.
    pub fn resample(&mut self) -> Result<(), FilterError> {
        let d = self.dims.state;
        let n = self.cfg.particles;
        self.cfg
            .resampling
            .resample(&self.w, &mut self.rng, &mut self.ancestors)?;
        for (k, &a) in self.ancestors.iter().enumerate() {
            self.x_alt[k * d..(k + 1) * d].copy_from_slice(&self.x[a * d..(a + 1) * d]);
        }
        std::mem::swap(&mut self.x, &mut self.x_alt);
        self.lw.fill(-(n as f64).ln());
        self.w.fill(1.0 / n as f64);
        self.ess = n as f64;
        Ok(())
    }
}

impl<M: SdeModel> BayesFilter for Pf<M> {
    fn name(&self) -> &'static str {
        "pf"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.t
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        if let Err(e) = self.try_reset(t, prior) {
            tracing::warn!("pf: reset rejected ({e}); belief kept");
        }
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.t, t, u, self.dims)?;
        let dur = t - self.t;
        if dur == 0.0 {
            return Ok(());
        }
        let steps = (dur / self.cfg.max_dt).ceil().max(1.0);
        let h = dur / steps;
        let steps = steps as usize;
        let d = self.dims.state;
        let mut alive = 0usize;
        let mut died = false;
        for (i, (src, dst)) in self
            .x
            .chunks_exact(d)
            .zip(self.x_alt.chunks_exact_mut(d))
            .enumerate()
        {
            let mut a = [0.0; MAX_STATE];
            let mut b = [0.0; MAX_STATE];
            a[..d].copy_from_slice(src);
            for _ in 0..steps {
                em_step(&self.model, &a[..d], u, h, &mut self.rng, &mut b[..d]);
                std::mem::swap(&mut a, &mut b);
            }
            dst.copy_from_slice(&a[..d]);
            if a[..d].iter().all(|v| v.is_finite()) {
                alive += (self.w[i] > 0.0) as usize;
            } else {
                died |= self.w[i] > 0.0;
            }
        }
        if alive == 0 {
            return Err(FilterError::Numerical("every particle diverged"));
        }
        std::mem::swap(&mut self.x, &mut self.x_alt);
        self.t = t;
        if died {
            // Diverged particles get weight 0; renormalise the survivors.
            for (i, xi) in self.x.chunks_exact(d).enumerate() {
                self.lw_new[i] = if xi.iter().all(|v| v.is_finite()) {
                    self.lw[i]
                } else {
                    f64::NEG_INFINITY
                };
            }
            let s = resample::normalize(&self.lw_new, &mut self.w)
                .ok_or(FilterError::Numerical("every particle diverged"))?;
            for (lw, &l) in self.lw.iter_mut().zip(&self.lw_new) {
                *lw = l - s.log_sum;
            }
            self.ess = s.ess;
        }
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let Dims {
            state: d, obs: m, ..
        } = self.dims;
        let n = self.cfg.particles;
        if meas.mask.iter().all(|i| i >= m) {
            return Ok(UpdateInfo {
                log_evidence: 0.0,
                ess: self.ess,
                resampled: false,
            });
        }
        let mut std = [0.0; MAX_OBS];
        match meas.std {
            Some(s) => std[..m].copy_from_slice(&s[..m]),
            None => self.model.obs_std(&mut std[..m]),
        }
        // Masked components as a 0/1 vector of 1/σ², and the constant part
        // of log p(y | x), which cancels in the weights.
        let mut inv_var = [0.0; MAX_OBS];
        let mut log_norm = 0.0;
        for j in meas.mask.iter().take_while(|&j| j < m) {
            inv_var[j] = 1.0 / (std[j] * std[j]);
            log_norm += std[j].ln() + HALF_LOG_2PI;
        }
        let mut g = [0.0; MAX_OBS];
        let mut r = [0.0; MAX_OBS];
        for (i, xi) in self.x.chunks_exact(d).enumerate() {
            if self.w[i] == 0.0 {
                self.lw_new[i] = f64::NEG_INFINITY;
                continue;
            }
            self.model.obs_mean(xi, &mut g[..m]);
            self.model.obs_residual(&meas.y[..m], &g[..m], &mut r[..m]);
            let mut q = 0.0;
            for j in 0..m {
                q += r[j] * r[j] * inv_var[j];
            }
            let ll = -0.5 * q;
            // NaN (a residual of ∞ − ∞) counts as impossible.
            self.lw_new[i] = if ll.is_nan() {
                f64::NEG_INFINITY
            } else {
                self.lw[i] + ll
            };
        }
        let s = resample::normalize(&self.lw_new, &mut self.w).ok_or(FilterError::Degenerate)?;
        for (lw, &l) in self.lw.iter_mut().zip(&self.lw_new) {
            *lw = l - s.log_sum;
        }
        self.ess = s.ess;
        let log_evidence = s.log_sum - log_norm;
        let resampled = s.ess < self.cfg.resample_threshold * n as f64;
        if resampled {
            self.resample()?;
        }
        Ok(UpdateInfo {
            log_evidence,
            ess: s.ess,
            resampled,
        })
    }

    fn belief(&self) -> Gaussian {
        let d = self.dims.state;
        let mut g = Gaussian::zeros(d);
        let mut mean = [0.0; MAX_STATE];
        for (xi, &w) in self.x.chunks_exact(d).zip(&self.w) {
            if w > 0.0 {
                for r in 0..d {
                    mean[r] += w * xi[r];
                }
            }
        }
        let cov = g.cov_mut();
        for (xi, &w) in self.x.chunks_exact(d).zip(&self.w) {
            if w > 0.0 {
                let mut e = [0.0; MAX_STATE];
                for r in 0..d {
                    e[r] = xi[r] - mean[r];
                }
                for c in 0..d {
                    let wc = w * e[c];
                    for r in c..d {
                        cov[r + c * d] += wc * e[r];
                    }
                }
            }
        }
        for c in 0..d {
            for r in (c + 1)..d {
                cov[c + r * d] = cov[r + c * d];
            }
        }
        g.mean_mut().copy_from_slice(&mean[..d]);
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::kalman::testmodels::oscillator;
    use crate::filter::kalman::Kalman;
    use crate::model::ship::{Ship, ShipParams};
    use crate::model::ObsMask;

    /// A seeded trajectory of the oscillator and its measurements: every
    /// third one carries only component 0 with an overridden σ.
    struct Data {
        times: Vec<f64>,
        ys: Vec<[f64; 2]>,
        us: Vec<f64>,
    }

    fn oscillator_data(steps: usize, dt: f64, seed: u64) -> Data {
        let model = oscillator([0.2, 0.3]);
        let mut rng = rng::stream(seed, 99);
        let mut x = [1.0, 0.0];
        let mut d = Data {
            times: vec![],
            ys: vec![],
            us: vec![],
        };
        for k in 1..=steps {
            let u = (0.7 * k as f64 * dt).sin();
            crate::model::discrete::em_integrate(&model, &mut x, &[u], dt, 1e-4, &mut rng);
            let mut y = [0.0; 2];
            crate::model::simulate_observation(&model, &x, &mut rng, &mut y);
            d.times.push(k as f64 * dt);
            d.ys.push(y);
            d.us.push(u);
        }
        d
    }

    fn run<F: BayesFilter>(f: &mut F, data: &Data) -> Vec<Gaussian> {
        let override_std = [0.5, 0.3];
        let mut out = vec![];
        for k in 0..data.times.len() {
            f.predict(data.times[k], &[data.us[k]]).unwrap();
            let meas = if k % 3 == 2 {
                Measurement {
                    y: &data.ys[k],
                    mask: ObsMask(0b01),
                    std: Some(&override_std),
                }
            } else {
                Measurement::full(&data.ys[k])
            };
            f.update(&meas).unwrap();
            out.push(f.belief());
        }
        out
    }

    pub(crate) fn prior() -> Gaussian {
        let mut p = Gaussian::diagonal(&[0.8, 0.2], &[0.5, 0.4]);
        p.set_cov(0, 1, 0.05);
        p.set_cov(1, 0, 0.05);
        p
    }

    /// Over R seeded runs the PF's mean and covariance agree with the exact
    /// Kalman filter: the average over runs is within 4.5 standard errors
    /// (estimated from the runs) plus an allowance of 1 % of the posterior
    /// std for the O(h) Euler–Maruyama and O(1/N) biases; and once the
    /// informative first updates (ESS ≪ N) are forgotten, each run's spread
    /// is of the Monte-Carlo order √(P/N) (≤ 3× for resampling).
    #[test]
    fn matches_the_kalman_filter_on_a_linear_gaussian_model() {
        let data = oscillator_data(20, 0.05, 5);
        let mut kf = Kalman::new(oscillator([0.2, 0.3]), &prior(), 0.0).unwrap();
        let exact = run(&mut kf, &data);
        let runs = 16;
        let n = 2000;
        let checkpoints = [4usize, 11, 19];
        // [checkpoint][run][m0, m1, p00, p01, p11]
        let mut stats = vec![vec![[0.0; 5]; runs]; checkpoints.len()];
        for r in 0..runs {
            let cfg = PfConfig {
                particles: n,
                max_dt: 0.001,
                seed: r as u64,
                ..PfConfig::default()
            };
            let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
            let beliefs = run(&mut pf, &data);
            for (c, &k) in checkpoints.iter().enumerate() {
                let b = &beliefs[k];
                stats[c][r] = [b.mean[0], b.mean[1], b.cov[0], b.cov[2], b.cov[3]];
            }
        }
        for (c, &k) in checkpoints.iter().enumerate() {
            let e = &exact[k];
            let want = [e.mean[0], e.mean[1], e.cov[0], e.cov[2], e.cov[3]];
            // Scale of each statistic: posterior std for means, variance
            // scale for covariance entries.
            let scale = [
                e.cov[0].sqrt(),
                e.cov[3].sqrt(),
                e.cov[0],
                (e.cov[0] * e.cov[3]).sqrt(),
                e.cov[3],
            ];
            for s in 0..5 {
                let vals: Vec<f64> = stats[c].iter().map(|v| v[s]).collect();
                let mean = vals.iter().sum::<f64>() / runs as f64;
                let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (runs - 1) as f64)
                    .sqrt();
                let se = sd / (runs as f64).sqrt();
                assert!(
                    (mean - want[s]).abs() < 4.5 * se + 0.01 * scale[s],
                    "step {k} stat {s}: PF {mean} ± {se} vs Kalman {}",
                    want[s]
                );
                // Monte-Carlo spread of one run: √(Var/N) for a mean,
                // √(2/N)·scale for a (co)variance; resampling inflates it.
                let mc = if s < 2 {
                    scale[s] / (n as f64).sqrt()
                } else {
                    scale[s] * (2.0 / n as f64).sqrt()
                };
                if c == checkpoints.len() - 1 {
                    assert!(sd < 3.0 * mc, "step {k} stat {s}: spread {sd} vs {mc}");
                }
            }
        }
    }

    #[test]
    fn impossible_measurement_is_degenerate_and_keeps_particles() {
        let cfg = PfConfig {
            particles: 200,
            ..PfConfig::default()
        };
        let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        pf.predict(0.1, &[0.0]).unwrap();
        let before = (pf.particles().to_vec(), pf.weights().to_vec());
        let e = pf.update(&Measurement::full(&[1e200, 0.0]));
        assert_eq!(e, Err(FilterError::Degenerate));
        assert_eq!(pf.particles(), &before.0[..]);
        assert_eq!(pf.weights(), &before.1[..]);
        // And it keeps working.
        pf.update(&Measurement::full(&[0.8, 0.1])).unwrap();
    }

    #[test]
    fn resampling_follows_the_ess_threshold() {
        let data = oscillator_data(10, 0.05, 1);
        for (thr, expect_any, expect_all) in [(0.0, false, false), (1.0, true, true)] {
            let cfg = PfConfig {
                particles: 300,
                resample_threshold: thr,
                ..PfConfig::default()
            };
            let mut pf = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
            let mut flags = vec![];
            let mut min_ess = f64::INFINITY;
            for k in 0..10 {
                pf.predict(data.times[k], &[data.us[k]]).unwrap();
                let info = pf.update(&Measurement::full(&data.ys[k])).unwrap();
                min_ess = min_ess.min(info.ess);
                assert!((info.ess - resample::ess(pf.weights())).abs() < 1e-6 || info.resampled);
                flags.push(info.resampled);
            }
            assert_eq!(flags.iter().any(|&f| f), expect_any);
            assert_eq!(flags.iter().all(|&f| f), expect_all);
            // The measurements are informative: weights degenerate somewhat.
            assert!(min_ess < 0.5 * 300.0, "min ESS {min_ess}");
        }
    }

    /// A bearing-only update of a ship prior centred on the negative x-axis,
    /// where bearings jump from π to −π: the posterior straddles the cut.
    /// With wrapped residuals the posterior lateral offset equals that of
    /// the same problem rotated by −90° (no cut) and the linearised answer;
    /// subtracting raw angles would kill the particles across the cut and
    /// bias it by ≈ 0.04 m.
    #[test]
    fn ship_bearing_residuals_wrap() {
        let params = ShipParams {
            range_std: 0.05,
            bearing_std: 0.01,
            ..ShipParams::paper(0.01)
        };
        let bearing_only = ObsMask(0b10);
        let cfg = PfConfig {
            particles: 20_000,
            resample_threshold: 0.0,
            seed: 3,
            ..PfConfig::default()
        };
        let std = [0.3, 0.3, 0.1, 0.1];
        // Truth at (−6, 0.006): bearing π − 0.001.
        let y_a = [6.0, std::f64::consts::PI - 0.001];
        let prior_a = Gaussian::diagonal(&[-6.0, 0.0, 0.0, 0.0], &std);
        let mut a = Pf::new(Ship::new(params.clone()).unwrap(), &cfg, &prior_a, 0.0).unwrap();
        a.update(&Measurement {
            y: &y_a,
            mask: bearing_only,
            std: None,
        })
        .unwrap();
        // Rotated by −90°: (x, y) ↦ (y, −x), truth at (0.006, 6).
        let y_b = [6.0, std::f64::consts::FRAC_PI_2 - 0.001];
        let prior_b = Gaussian::diagonal(&[0.0, 6.0, 0.0, 0.0], &std);
        let mut b = Pf::new(Ship::new(params).unwrap(), &cfg, &prior_b, 0.0).unwrap();
        b.update(&Measurement {
            y: &y_b,
            mask: bearing_only,
            std: None,
        })
        .unwrap();
        let lat_a = a.belief().mean[1];
        let lat_b = b.belief().mean[0];
        // Linearised: lateral prior σ 0.3 m ≙ 0.05 rad, bearing σ 0.01 rad.
        let lin = 0.006 * 0.05f64.powi(2) / (0.05f64.powi(2) + 0.01f64.powi(2));
        assert!((lat_a - lat_b).abs() < 0.01, "{lat_a} vs rotated {lat_b}");
        assert!((lat_a - lin).abs() < 0.01, "{lat_a} vs linearised {lin}");
    }

    #[test]
    fn config_parses_with_defaults_and_rejects_bad_values() {
        let c: PfConfig = toml::from_str("particles = 500\nresampling = \"residual\"").unwrap();
        assert_eq!(c.particles, 500);
        assert_eq!(c.resampling, Scheme::Residual);
        assert_eq!(c.resample_threshold, 0.5);
        assert!(toml::from_str::<PfConfig>("particle = 5").is_err());
        assert!(toml::from_str::<PfConfig>("resampling = \"bogus\"").is_err());
        for (bad, key) in [
            (
                PfConfig {
                    particles: 0,
                    ..Default::default()
                },
                "particles",
            ),
            (
                PfConfig {
                    resample_threshold: 1.5,
                    ..Default::default()
                },
                "resample_threshold",
            ),
            (
                PfConfig {
                    max_dt: 0.0,
                    ..Default::default()
                },
                "max_dt",
            ),
        ] {
            assert_eq!(bad.validate().unwrap_err().key, key);
            assert!(Pf::new(oscillator([0.2, 0.3]), &bad, &prior(), 0.0).is_err());
        }
    }

    #[test]
    fn same_seed_same_result() {
        let data = oscillator_data(5, 0.05, 2);
        let cfg = PfConfig {
            particles: 100,
            seed: 9,
            ..Default::default()
        };
        let mut a = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        let mut b = Pf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
        assert_eq!(run(&mut a, &data), run(&mut b, &data));
    }
}
