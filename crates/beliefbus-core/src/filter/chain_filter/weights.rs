//! The prior on the chain's states and the likelihood helpers the smoother
//! and the decoders share with the filter.

use crate::belief::Gaussian;
use crate::chain::linalg::cholesky;
use crate::chain::Chain;
use crate::filter::live_chain::mass::{gaussian_log_weight, ObsTerms};
use crate::model::{Measurement, SdeModel};
use crate::{MAX_OBS, MAX_STATE};

/// The prior N(mean, cov) as a mass function on the chain's states:
/// φ(z) ∝ N(z; mean, cov) · vol(z) (see the module doc). A singular
/// covariance puts all mass on the state nearest the mean. `scratch` has
/// the length of `out` (= chain.len()).
pub fn prior_weights(chain: &Chain, prior: &Gaussian, out: &mut [f64], scratch: &mut [f64]) {
    let d = chain.dim();
    let n = chain.len();
    let mut l = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(prior.cov());
    if !cholesky(&mut l[..d * d], d) {
        let mut near = Vec::with_capacity(1);
        chain.nearest(prior.mean(), 1, &mut near);
        out.fill(0.0);
        if let Some(&(j, _)) = near.first() {
            out[j as usize] = 1.0;
        }
        return;
    }
    let mut lmax = f64::NEG_INFINITY;
    for i in 0..n {
        let (z, vol) = (chain.state(i), chain.cell_volume(i));
        let lw = gaussian_log_weight(&l[..d * d], &prior.mean[..d], z, vol);
        scratch[i] = lw;
        lmax = lmax.max(lw);
    }
    for i in 0..n {
        out[i] = (scratch[i] - lmax).exp();
    }
    normalise(out);
}

/// log p(y | z) up to the constant Σ(−log σ_i − ½ log 2π), for every state
/// from its precomputed observation mean (`obs_mean`, n × m), into `out`.
/// Returns the maximum.
pub fn log_likelihoods<M: SdeModel>(
    model: &M,
    obs_mean: &[f64],
    meas: &Measurement,
    out: &mut [f64],
) -> f64 {
    let m = model.dims().obs;
    let (terms, _) = ObsTerms::new(model, meas);
    let mut r = [0.0; MAX_OBS];
    let mut lmax = f64::NEG_INFINITY;
    for (z, o) in out.iter_mut().enumerate() {
        *o = terms.log_lik(
            model,
            &meas.y[..m],
            &obs_mean[z * m..(z + 1) * m],
            &mut r[..m],
        );
        lmax = lmax.max(*o);
    }
    lmax
}

/// Observation means g(z) of every state, n × m.
pub fn observation_means<M: SdeModel>(model: &M, states: &[f64], d: usize) -> Vec<f64> {
    let m = model.dims().obs;
    let n = states.len() / d;
    let mut g = vec![0.0; n * m];
    for i in 0..n {
        model.obs_mean(&states[i * d..(i + 1) * d], &mut g[i * m..(i + 1) * m]);
    }
    g
}

/// Normalise to sum 1; false if the sum is not positive and finite.
pub(crate) fn normalise(w: &mut [f64]) -> bool {
    let s: f64 = w.iter().sum();
    if !(s > 0.0 && s.is_finite()) {
        return false;
    }
    let inv = 1.0 / s;
    for v in w.iter_mut() {
        *v *= inv;
    }
    true
}
