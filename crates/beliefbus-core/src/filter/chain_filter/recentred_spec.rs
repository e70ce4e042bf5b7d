//! [`RecentredSpec`]: a [`RecentredChainFilter`] built from a model, the
//! covariance its local states are drawn around, and the settings measured
//! on the drifting ship (`docs/ship-state-counts.md`, section 4).
//!
//! ```text
//! q = N(0, spread² P_ref)                         the local states' law
//! states: oversample·n draws from q thinned to n by sample elimination
//!         (chain::placement::eliminate) when `even`, else n draws
//! chain:  advected moment-matched kernel, τ = the observation period,
//!         k = ⌈knn_c log n⌉ neighbours, built once for the model itself
//! filter: re-installed every `every` observations by importance weights
//!         N(z; x̂, P̂)/q(z), covariance matched `cov_match` times
//! ```
//!
//! P_ref should be about the posterior's covariance after an update (e.g.
//! [`crate::chain::steady::steady_posterior`] of the model linearised at a
//! typical operating point): states much wider than the belief waste
//! effective states, narrower ones cut its tails. The model's drift must
//! be affine and its noise additive wherever the belief goes (see
//! [`super::recentred`]); on other models the frame is first-order.

use super::recentred::{Install, RecentredChainFilter, RecentredConfig};
use crate::belief::Gaussian;
use crate::chain::{Chain, ChainConfig, ChainError, NearRule, Sampler};
use crate::model::SdeModel;
use crate::rng::SimRng;

/// Settings of a re-centred chain filter (defaults: the ship's measured
/// choice, parity with PF-100 at 100–150 states).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecentredSpec {
    /// Chain states n.
    pub states: usize,
    /// Std inflation of the local states' law over P_ref.
    pub spread: f64,
    /// Re-install every this many predictions.
    pub every: usize,
    /// Covariance corrections per install.
    pub cov_match: usize,
    /// Thin `oversample`·n candidates to n by sample elimination.
    pub even: bool,
    pub oversample: usize,
    /// Neighbour constant c of k = ⌈c log n⌉.
    pub knn_c: f64,
}

impl Default for RecentredSpec {
    fn default() -> Self {
        Self {
            states: 150,
            spread: 2.0,
            every: 10,
            cov_match: 2,
            even: true,
            oversample: 4,
            knn_c: 1.5,
        }
    }
}

impl RecentredSpec {
    /// The local states' law N(0, spread² `shape`).
    pub fn sampling_law(&self, shape: &Gaussian) -> Gaussian {
        let mut q = *shape;
        q.mean_mut().fill(0.0);
        for v in q.cov_mut() {
            *v *= self.spread * self.spread;
        }
        q
    }

    /// Build the chain (states around N(0, spread² `shape`), advected
    /// with step `period`) and the filter, started at N(`prior`) at `t0`.
    pub fn build<M: SdeModel + Clone>(
        &self,
        model: &M,
        shape: &Gaussian,
        period: f64,
        prior: &Gaussian,
        t0: f64,
        rng: &mut SimRng,
    ) -> Result<RecentredChainFilter<M>, ChainError> {
        let d = model.dims().state;
        if self.states < 2 || !(self.spread > 0.0) || self.oversample == 0 {
            return Err(ChainError::Config(
                "re-centred chain: states ≥ 2, spread > 0 and oversample ≥ 1",
            ));
        }
        let q = self.sampling_law(shape);
        let sampler = Sampler::around(&q, 1.0, 0.0).ok_or(ChainError::Config(
            "re-centred chain: the sampling covariance must be positive definite",
        ))?;
        let m = if self.even {
            self.oversample * self.states
        } else {
            self.states
        };
        let mut cand = vec![0.0; m * d];
        for x in cand.chunks_exact_mut(d) {
            sampler.sample(model.bounds(), rng, x);
        }
        let pts = if self.even {
            crate::chain::placement::eliminate(&cand, d, self.states)
        } else {
            cand
        };
        let cfg = ChainConfig::moment_matched(d)
            .with_near(NearRule::Knn { c: self.knn_c })
            .with_step(period);
        let chain = Chain::batch(model, cfg, &pts)?;
        let rcfg = RecentredConfig {
            every: self.every,
            ess_fraction: 0.0,
            install: Install::Importance,
            cov_match: self.cov_match,
        };
        let mut f = RecentredChainFilter::new(model.clone(), chain, &q, period, rcfg)?;
        crate::filter::BayesFilter::reset(&mut f, t0, prior);
        Ok(f)
    }
}
