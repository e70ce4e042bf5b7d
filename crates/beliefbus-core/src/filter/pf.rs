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
//! Options (see [`super::regularise`]): `regularisation` c > 0 jitters the
//! particles after every resampling with a Gaussian kernel of bandwidth
//! c·h_opt·S^{1/2} (S the weighted covariance before resampling; Musso,
//! Oudjane & Le Gland's regularised PF); off by default, so a seeded run
//! draws the same numbers as without it. Every update whose ESS (before
//! resampling) falls below `collapse_fraction`·N, or whose weights all
//! vanish, is counted in [`Pf::collapses`] — a lost filter is visible in
//! its stats, not only in its error.
//!
//! Everything is sized at construction: `predict` and `update` do not
//! allocate. A particle whose state becomes non-finite gets weight 0; if all
//! weights vanish the step is refused (`Degenerate` for an update,
//! `Numerical` for a prediction) and the previous particles are kept.

use super::build::{self, BuildError, ConfigError};
use super::gauss::{self, HALF_LOG_2PI};
use super::gauss_state::{predict_span, reset_or_keep};
use super::regularise::{self, collapse_threshold, DEFAULT_COLLAPSE_FRACTION};
use super::resample::Scheme;
use super::{check_measurement, BayesFilter, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::math::weights;
use crate::model::{em_step, Dims, Measurement, SdeModel};
use crate::rng::{self, SimRng};
use crate::{MAX_OBS, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// RNG stream id of the particle filter (mixed with the config seed).
pub const PF_STREAM: u64 = 0x5046; // "PF"

/// Settings of the bootstrap particle filter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
    /// Regularised resampling: after each resampling, jitter the particles
    /// with a Gaussian kernel of bandwidth `regularisation` × the optimal
    /// h_opt = (4/(d+2))^{1/(d+4)} N^{−1/(d+4)} times the square root of
    /// their weighted covariance (Musso, Oudjane & Le Gland). 0: off (the
    /// plain bootstrap filter); 1: the optimal bandwidth for a Gaussian
    /// posterior.
    pub regularisation: f64,
    /// An update whose ESS (before resampling) is below max(f·N, 2) for
    /// this fraction f, or whose weights all vanish, counts as a collapse
    /// ([`Pf::collapses`]; default 0.01; 0: only vanished weights).
    pub collapse_fraction: f64,
}

impl Default for PfConfig {
    fn default() -> Self {
        Self {
            particles: 1000,
            resample_threshold: 0.5,
            max_dt: 0.01,
            resampling: Scheme::Systematic,
            seed: 0,
            regularisation: 0.0,
            collapse_fraction: DEFAULT_COLLAPSE_FRACTION,
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
        if !(self.regularisation.is_finite() && self.regularisation >= 0.0) {
            return Err(ConfigError::new(
                "regularisation",
                format!(
                    "must be a finite bandwidth factor ≥ 0 (0: off), got {}",
                    self.regularisation
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.collapse_fraction) {
            return Err(ConfigError::new(
                "collapse_fraction",
                format!("must be in [0, 1], got {}", self.collapse_fraction),
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
    /// Updates that collapsed (ESS < collapse_fraction·N or all weights
    /// vanished) and predictions in which every particle diverged.
    collapses: u64,
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
            collapses: 0,
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
    /// Effective sample size 1/Σ W² of the current normalised weights
    /// (kept from the last normalisation, [`weights::normalise`]).
    pub fn ess(&self) -> f64 {
        self.ess
    }
    /// Steps that collapsed since construction: updates whose ESS before
    /// resampling fell below `collapse_fraction`·N or whose weights all
    /// vanished, and predictions in which every particle diverged.
    pub fn collapses(&self) -> u64 {
        self.collapses
    }
    /// The config the filter was built with.
    pub fn config(&self) -> &PfConfig {
        &self.cfg
    }
    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// Resample unconditionally with the configured scheme, then (with
    /// `regularisation` > 0) jitter the particles by the kernel scaled by
    /// their weighted covariance before resampling.
    pub fn resample(&mut self) -> Result<(), FilterError> {
        let d = self.dims.state;
        let n = self.cfg.particles;
        let mut l = [0.0; MAX_STATE * MAX_STATE];
        let jitter = self.cfg.regularisation > 0.0
            && regularise::weighted_cov_factor(&self.x, &self.w, d, &mut l[..d * d]);
        self.cfg
            .resampling
            .resample(&self.w, &mut self.rng, &mut self.ancestors)?;
        for (k, &a) in self.ancestors.iter().enumerate() {
            self.x_alt[k * d..(k + 1) * d].copy_from_slice(&self.x[a * d..(a + 1) * d]);
        }
        std::mem::swap(&mut self.x, &mut self.x_alt);
        if jitter {
            let h = self.cfg.regularisation * regularise::optimal_bandwidth(n, d);
            regularise::jitter(&mut self.x, d, &l[..d * d], h, &mut self.rng);
        }
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
        reset_or_keep("pf", self.try_reset(t, prior));
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        let Some(dur) = predict_span(self.t, t, u, self.dims)? else {
            return Ok(());
        };
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
            self.collapses += 1;
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
            let s = weights::normalise(&self.lw_new, &mut self.w)
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
        let Some(s) = weights::normalise(&self.lw_new, &mut self.w) else {
            self.collapses += 1;
            return Err(FilterError::Degenerate);
        };
        for (lw, &l) in self.lw.iter_mut().zip(&self.lw_new) {
            *lw = l - s.log_sum;
        }
        self.ess = s.ess;
        if s.ess < collapse_threshold(self.cfg.collapse_fraction, n) {
            self.collapses += 1;
        }
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

    fn ess_collapses(&self) -> Option<u64> {
        Some(self.collapses)
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
#[path = "pf_tests.rs"]
mod tests;

#[cfg(test)]
#[path = "pf_regularise_tests.rs"]
mod regularise_tests;
