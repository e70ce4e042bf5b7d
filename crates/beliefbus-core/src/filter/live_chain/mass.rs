//! What both chain filters ([`super::LiveChainFilter`] on snapshots and
//! [`crate::filter::chain_filter::ChainFilter`] on an owned chain) compute
//! the same way on a mass function φ over chain states (thesis §3.3,
//! eq. 3.6):
//!
//! ```text
//! log p(y | z) = −½ Σ_{i∈mask} r_i(z)²/σ_i² + Σ_{i∈mask} (−ln σ_i − ½ ln 2π),   r = y ⊖ g(z)
//! φ(z) ∝ N(z; x̂, P) · vol(z)   (a Gaussian installed on the states)
//! ```
//!
//! Each filter keeps its own loop (the live one over all states, the batch
//! one over its sparse support with a flush histogram); the arithmetic of a
//! state's term is here, once, so both give the same value bit for bit.

use crate::math::linalg::forward_sub;
use crate::model::{Measurement, SdeModel};
use crate::{MAX_OBS, MAX_STATE};

/// ½ ln 2π.
pub(crate) const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;

/// The observed components of a measurement and their inverse variances
/// (the mask as a short index list: `ObsMask::iter` scans 32 bits).
pub(crate) struct ObsTerms {
    idx: [usize; MAX_OBS],
    inv_var: [f64; MAX_OBS],
    nm: usize,
}

impl ObsTerms {
    /// The terms of `meas` (its std, else the model's) and the constant
    /// Σ_{i∈mask} (−ln σ_i − ½ ln 2π) of its log-likelihood.
    pub(crate) fn new<M: SdeModel + ?Sized>(model: &M, meas: &Measurement) -> (Self, f64) {
        let m = model.dims().obs;
        let mut std = [0.0; MAX_OBS];
        match meas.std {
            Some(s) => std[..m].copy_from_slice(&s[..m]),
            None => model.obs_std(&mut std[..m]),
        }
        let mut t = Self {
            idx: [0usize; MAX_OBS],
            inv_var: [0.0; MAX_OBS],
            nm: 0,
        };
        let mut cst = 0.0;
        for i in meas.mask.iter().take_while(|&i| i < m) {
            t.idx[t.nm] = i;
            t.inv_var[t.nm] = 1.0 / (std[i] * std[i]);
            t.nm += 1;
            cst -= std[i].ln() + HALF_LOG_2PI;
        }
        (t, cst)
    }

    /// −½ Σ r_i²/σ_i² over the observed components, r = y ⊖ g (the
    /// model's residual, into the scratch `r` of length m).
    #[inline]
    pub(crate) fn log_lik<M: SdeModel + ?Sized>(
        &self,
        model: &M,
        y: &[f64],
        g: &[f64],
        r: &mut [f64],
    ) -> f64 {
        model.obs_residual(y, g, r);
        let mut q = 0.0;
        for k in 0..self.nm {
            let ri = r[self.idx[k]];
            q += ri * ri * self.inv_var[k];
        }
        -0.5 * q
    }
}

/// ln(N(z; mean, LLᵀ)·vol) up to a constant, with `l` the d × d Cholesky
/// factor of the covariance: −½‖L⁻¹(z − mean)‖² + ln vol (vol floored at
/// 1e-300 so an empty cell is improbable, not impossible).
#[inline]
pub(crate) fn gaussian_log_weight(l: &[f64], mean: &[f64], z: &[f64], vol: f64) -> f64 {
    let d = z.len();
    let mut y = [0.0; MAX_STATE];
    for a in 0..d {
        y[a] = z[a] - mean[a];
    }
    forward_sub(l, d, &mut y[..d]);
    let q: f64 = y[..d].iter().map(|v| v * v).sum();
    -0.5 * q + vol.max(1e-300).ln()
}
