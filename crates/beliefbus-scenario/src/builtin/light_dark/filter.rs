//! Backend `chain-pomdp`: the chain filter over the policy's chain states,
//! one decision period per sample,
//!
//! ```text
//! b̄(z') = Σ_z b(z) T(z' | z, a)          a the action of the applied velocity v
//! b(z')  ∝ b̄(z') p(y | z'),  p(y | z) = N(y; z, G(z)²)
//! ```
//!
//! T's rows for a control are the chain's transition probabilities under
//! it over one period (for the reference control exactly the chain
//! filter's p^δ; `beliefbus_pomdp::chain_pomdp`), and the update uses the
//! continuous measurement, so this is the chain filter's predict and
//! update — and exactly the belief the α-vectors were solved over. An
//! episode's first sample (flag n = 1) restarts from b₀ and only updates.
//! Preallocated: no allocation per step.
//!
//! `predict(t, u)` only moves the clock: the velocity that moved the agent
//! comes with the measurement (y, v, n), so the filter propagates with the
//! plant's control even when a control arrived late. A restarted filter
//! starts from b₀ (the message's Gaussian block cannot restore the chain
//! distribution) until the next episode starts.

use super::encoding::{write_chain, STATE};
use super::model::LightObs;
use super::LightDarkSystem;
use crate::backends::FilterContext;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{
    check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo,
};
use beliefbus_core::model::{Dims, Measurement};
use beliefbus_pomdp::chain_pomdp::ChainPomdp;
use std::sync::Arc;

/// The backend.
pub struct ChainBeliefFilter {
    sys: LightDarkSystem,
    cp: Arc<ChainPomdp>,
    obs: LightObs,
    /// b over the POMDP's states (the absorbing one last, always 0).
    b: Vec<f64>,
    pred: Vec<f64>,
    dims: Dims,
    time: f64,
    started: bool,
    belief: Gaussian,
}

impl ChainBeliefFilter {
    pub fn new(sys: &LightDarkSystem, ctx: &FilterContext) -> Self {
        let cp = sys.pomdp.clone();
        let b = cp.pomdp.start.clone();
        let mut f = Self {
            sys: sys.clone(),
            pred: vec![0.0; b.len()],
            b,
            cp,
            obs: sys.params.obs(),
            dims: crate::System::dims(sys),
            time: ctx.t0,
            started: false,
            belief: Gaussian::zeros(STATE),
        };
        f.summarise();
        f
    }

    /// The distribution over the chain states.
    pub fn chain_belief(&self) -> &[f64] {
        &self.b[..self.cp.n_chain()]
    }

    fn restart(&mut self) {
        self.b.copy_from_slice(&self.cp.pomdp.start);
    }

    /// Mean and variance of x, and the distribution for the controller.
    fn summarise(&mut self) {
        let n = self.cp.n_chain();
        let (mut m, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let z = self.cp.state(i)[0];
            m += self.b[i] * z;
            s2 += self.b[i] * z * z;
        }
        let g = &mut self.belief;
        g.mean[0] = m;
        g.set_cov(0, 0, (s2 - m * m).max(0.0));
        g.set_cov(1, 1, 1e-6);
        g.set_cov(2, 2, 1e-6);
        write_chain(g, &self.b[..n]);
    }

    /// b ∝ b̄ p(y|z) from `pred`; false when every likelihood vanished.
    fn condition(&mut self, y: f64) -> Option<(f64, f64)> {
        let n = self.cp.n_chain();
        let mut lmax = f64::NEG_INFINITY;
        for i in 0..n {
            if self.pred[i] > 0.0 {
                lmax = lmax.max(self.obs.log_lik(self.cp.state(i)[0], y));
            }
        }
        if !lmax.is_finite() {
            return None;
        }
        let mut total = 0.0;
        for i in 0..n {
            let w = if self.pred[i] > 0.0 {
                self.pred[i] * (self.obs.log_lik(self.cp.state(i)[0], y) - lmax).exp()
            } else {
                0.0
            };
            self.b[i] = w;
            total += w;
        }
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        let mut sq = 0.0;
        for v in &mut self.b[..n] {
            *v /= total;
            sq += *v * *v;
        }
        self.b[n..].fill(0.0);
        // log p(y | past) = lmax + ln Σ b̄ e^{ll − lmax} − ½ ln 2π.
        let evidence = lmax + total.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
        Some((evidence, 1.0 / sq))
    }
}

impl BayesFilter for ChainBeliefFilter {
    fn name(&self) -> &'static str {
        super::CHAIN_FILTER
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.time
    }
    fn reset(&mut self, t: f64, _prior: &Gaussian) {
        self.restart();
        self.started = false;
        self.time = t;
        self.summarise();
    }
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.time, t, u, self.dims)?;
        self.time = t;
        Ok(())
    }
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        if !(0..3).all(|i| meas.mask.contains(i)) {
            return Err(FilterError::Dimension {
                what: "observation mask (needs y, the applied velocity and the episode flag)",
                got: meas.mask.count(),
                expected: 3,
            });
        }
        let (y, v, first) = (meas.y[0], meas.y[1], meas.y[2]);
        if !(y.is_finite() && v.is_finite() && first.is_finite()) {
            return Err(FilterError::NonFinite("observation"));
        }
        if first > 0.5 || !self.started {
            self.started = true;
            self.pred.copy_from_slice(&self.cp.pomdp.start);
        } else {
            let a = self.sys.nearest_action(v);
            self.cp.predict(&self.b, a, &mut self.pred);
        }
        match self.condition(y) {
            Some((log_evidence, ess)) => {
                self.summarise();
                Ok(UpdateInfo {
                    log_evidence,
                    ess,
                    resampled: false,
                })
            }
            None => {
                // Keep the prediction: the best the filter has.
                let n = self.cp.n_chain();
                let total: f64 = self.pred[..n].iter().sum();
                if total > 0.0 {
                    for i in 0..n {
                        self.b[i] = self.pred[i] / total;
                    }
                    self.summarise();
                }
                Err(FilterError::Degenerate)
            }
        }
    }
    fn belief(&self) -> Gaussian {
        self.belief
    }
}
