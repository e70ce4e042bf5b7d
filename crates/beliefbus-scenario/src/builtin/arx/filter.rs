//! Backend `rbpf-changepoint`: the fast Rao-Blackwellised particle filter
//! of Chen, Lai & Wu §3.3 ([`ArxOnline`]) behind the pipeline's
//! [`BayesFilter`] trait.
//!
//! `predict(t, u)` only moves the clock: the system steps at samples, and
//! the input that entered y_t comes with the measurement (y_t, u_{t−1}).
//! `update` feeds u_{t−1} then y_t to the filter and summarises the
//! particles (C_j, μ_j, V_j, W_j) as the published Gaussian:
//!
//! ```text
//! θ̂ = Σ W_j μ_j                         (15)
//! P = Σ W_j (V_j + μ_j μ_jᵀ) − θ̂ θ̂ᵀ      (mixture covariance)
//! r̂ = min{ r : Σ_j W_j 1{t − C_j ≤ r} > ½ }   (posterior median run length)
//! ```
//!
//! r̂ is in seconds like the state; P(a change in [s, t]) > ½ exactly when
//! t − r̂ ≥ s, which is what the detection delay asks. The initial segment
//! counts from step 1. Before t₀ the belief is the prior. A restarted
//! filter (or `reset`) starts again from the law of θ: the particles'
//! statistics cannot be recovered from a Gaussian.

use super::{ArxSystem, RUN_LENGTH, STATE, T0};
use crate::backends::FilterContext;
use beliefbus_changepoint::arx::online::ArxOnline;
use beliefbus_changepoint::arx::rbpf::ArxRbpfConfig;
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::ChangepointError;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{
    check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo,
};
use beliefbus_core::model::{Dims, Measurement};

/// The backend.
#[derive(Debug)]
pub struct ArxRbpfFilter {
    online: ArxOnline<3>,
    cfg: ArxRbpfConfig,
    prior: ThetaPrior<3>,
    seed: u64,
    resets: u64,
    dims: Dims,
    dt: f64,
    time: f64,
    /// y_t, y_{t−1} as observed.
    y: [f64; 2],
    belief: Gaussian,
    /// (run length in steps, weight) per particle, sorted for the median.
    runs: Vec<(u64, f64)>,
}

fn rbpf_error(e: ChangepointError) -> FilterError {
    match e {
        ChangepointError::WeightsVanished { .. } => FilterError::Degenerate,
        ChangepointError::NonFinite { .. } => FilterError::NonFinite("observation"),
        _ => FilterError::Numerical("change-point filter"),
    }
}

impl ArxRbpfFilter {
    /// From the scenario's `[arx.filter]` settings; the stream is
    /// `ctx.seed`.
    pub fn new(sys: &ArxSystem, ctx: &FilterContext) -> Result<Self, String> {
        let p = &sys.params.filter;
        let cfg = ArxRbpfConfig {
            particles: p.particles,
            cv2_bound: p.cv2_bound,
            scheme: sys.scheme,
            rho: sys.params.rho,
            tilt: None,
        };
        let prior = sys.theta_prior();
        let online = ArxOnline::new(2, prior, cfg, crate::rng::stream(ctx.seed, 0))
            .map_err(|e| e.to_string())?;
        let dims = crate::System::dims(sys);
        let mut f = Self {
            online,
            cfg,
            prior,
            seed: ctx.seed,
            resets: 0,
            dims,
            dt: ctx.sample_dt,
            time: ctx.t0,
            y: [0.0; 2],
            belief: Gaussian::zeros(STATE),
            runs: Vec::with_capacity(p.particles),
        };
        f.summarise();
        Ok(f)
    }

    /// The particle summary above into `self.belief`.
    fn summarise(&mut self) {
        let mut g = Gaussian::zeros(STATE);
        let t = self.online.t();
        let f = self.online.filter();
        if t < T0 {
            for i in 0..3 {
                g.mean[i] = self.prior.mu[i];
                for j in 0..3 {
                    g.set_cov(i, j, self.prior.v[i][j]);
                }
            }
            g.mean[RUN_LENGTH] = t.saturating_sub(1) as f64 * self.dt;
        } else {
            let w = f.weights();
            let mut second = [[0.0; 3]; 3];
            self.runs.clear();
            for (j, &wj) in w.iter().enumerate() {
                let Some((c, mu, v)) = f.particle(j) else {
                    continue;
                };
                for a in 0..3 {
                    g.mean[a] += wj * mu[a];
                    for b in 0..3 {
                        second[a][b] += wj * (v[a][b] + mu[a] * mu[b]);
                    }
                }
                // The filter's step c is the caller's c + t₀ − 1; its
                // first segment starts at the caller's step 1.
                let start = if c <= 1 { 1 } else { c + T0 - 1 };
                self.runs.push((t.saturating_sub(start), wj));
            }
            for a in 0..3 {
                for b in 0..3 {
                    g.set_cov(a, b, second[a][b] - g.mean[a] * g.mean[b]);
                }
            }
            self.runs.sort_unstable_by_key(|r| r.0);
            let (mut acc, mut median, mut m1, mut m2) = (0.0, 0u64, 0.0, 0.0);
            let mut found = false;
            for &(r, wj) in &self.runs {
                acc += wj;
                if !found && acc > 0.5 {
                    median = r;
                    found = true;
                }
                m1 += wj * r as f64;
                m2 += wj * (r as f64).powi(2);
            }
            if !found {
                median = self.runs.last().map_or(0, |r| r.0);
            }
            g.mean[RUN_LENGTH] = median as f64 * self.dt;
            g.set_cov(
                RUN_LENGTH,
                RUN_LENGTH,
                (m2 - m1 * m1).max(0.0) * self.dt * self.dt,
            );
        }
        g.mean[3] = self.y[0];
        g.mean[4] = self.y[1];
        self.belief = g;
    }

    /// The underlying filter.
    pub fn online(&self) -> &ArxOnline<3> {
        &self.online
    }
}

impl BayesFilter for ArxRbpfFilter {
    fn name(&self) -> &'static str {
        super::RBPF
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.time
    }
    fn reset(&mut self, t: f64, _prior: &Gaussian) {
        // A fresh stream per reset keeps runs reproducible.
        self.resets += 1;
        let rng = crate::rng::stream(self.seed, self.resets);
        if let Ok(o) = ArxOnline::new(2, self.prior, self.cfg, rng) {
            self.online = o;
        }
        self.time = t;
        self.y = [0.0; 2];
        self.summarise();
    }
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.time, t, u, self.dims)?;
        self.time = t;
        Ok(())
    }
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        if !(meas.mask.contains(0) && meas.mask.contains(1)) {
            return Err(FilterError::Dimension {
                what: "observation mask (needs y and u)",
                got: meas.mask.count(),
                expected: 2,
            });
        }
        let (y, u_prev) = (meas.y[0], meas.y[1]);
        let before = self.online.filter().resamplings();
        self.online.apply(u_prev).map_err(rbpf_error)?;
        self.online.observe(y).map_err(rbpf_error)?;
        self.y = [y, self.y[0]];
        self.summarise();
        let w = self.online.filter().weights();
        let ess = if self.online.t() < T0 {
            w.len() as f64
        } else {
            1.0 / w.iter().map(|v| v * v).sum::<f64>()
        };
        Ok(UpdateInfo {
            // The filter's normalising constant is not kept across
            // rejuvenations: no evidence figure.
            log_evidence: f64::NAN,
            ess,
            resampled: self.online.filter().resamplings() > before,
        })
    }
    fn belief(&self) -> Gaussian {
        self.belief
    }
}
