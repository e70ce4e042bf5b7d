//! What the Gaussian filters (Kalman, EKF, UKF) have in common around their
//! own prediction: the belief N(m, P) at time t on stack buffers, its start
//! and restart from a prior, the rule that a predicted or updated (m, P) is
//! accepted only when finite and positive semi-definite (otherwise the
//! previous belief is kept), and the pieces of the masked measurement
//! update that do not depend on how the filter linearises g:
//!
//! ```text
//! rows i ∈ mask (p of them),   R = diag(σ_i²) (the measurement's σ or the model's)
//! Kᵀ = S⁻¹ Cᵀ,   log p(y) = −½ rᵀ S⁻¹ r − ½ log det S − (p/2) log 2π,   m⁺ = m + K r
//! ```
//!
//! with S the innovation covariance (R included) and C the state–innovation
//! cross covariance: C = P Hᵀ for the Kalman filter and the EKF (Joseph
//! form in `gauss`), the sigma-point sum for the UKF.
//!
//! The particle filter shares the start/restart checks of the time and the
//! prior and the `predict` preamble.

use super::gauss::{self, Mat, ObsMat, HALF_LOG_2PI};
use super::{check_predict, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::math::linalg;
use crate::model::{Dims, Measurement, ObsMask, SdeModel};
use crate::{MAX_OBS, MAX_STATE};

/// The belief N(mean, cov) of dimension `d` at time `t`.
#[derive(Clone, Debug)]
pub(crate) struct GaussState {
    pub d: usize,
    pub t: f64,
    pub mean: [f64; MAX_STATE],
    pub cov: Mat,
}

impl GaussState {
    /// The prior N(mean, cov) at `t0`, after checking both.
    pub fn new(d: usize, prior: &Gaussian, t0: f64) -> Result<Self, FilterError> {
        gauss::check_prior(prior, d)?;
        check_time(t0)?;
        let mut s = Self {
            d,
            t: t0,
            mean: [0.0; MAX_STATE],
            cov: [0.0; MAX_STATE * MAX_STATE],
        };
        s.set(prior);
        Ok(s)
    }

    /// Restart from `prior` at `t`; an invalid one is refused and the
    /// belief kept.
    pub fn try_reset(&mut self, t: f64, prior: &Gaussian) -> Result<(), FilterError> {
        check_time(t)?;
        gauss::check_prior(prior, self.d)?;
        self.t = t;
        self.set(prior);
        Ok(())
    }

    fn set(&mut self, prior: &Gaussian) {
        let d = self.d;
        self.mean[..d].copy_from_slice(prior.mean());
        self.cov[..d * d].copy_from_slice(prior.cov());
        gauss::symmetrize(&mut self.cov, d);
    }

    /// Replace the belief by (m, P) if m is finite and P positive
    /// semi-definite; otherwise keep it and return `Numerical(why)`.
    pub fn accept(&mut self, m: &[f64], p: &[f64], why: &'static str) -> Result<(), FilterError> {
        let d = self.d;
        if !m[..d].iter().all(|v| v.is_finite()) || !gauss::is_psd(p, d) {
            return Err(FilterError::Numerical(why));
        }
        self.mean[..d].copy_from_slice(&m[..d]);
        self.cov[..d * d].copy_from_slice(&p[..d * d]);
        Ok(())
    }

    /// Masked Joseph-form update (the Kalman filter and the EKF):
    ///
    /// ```text
    /// S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,   m⁺ = m + K r,
    /// P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ
    /// ```
    ///
    /// `h` is the full m × d observation matrix (Jacobian), `r` the full
    /// innovation y ⊖ ŷ (length m, already wrapped by the model), `std` the
    /// per-component σ (length m). Only the components in `mask` are used.
    /// Returns log p(y) of the masked components; on failure (S or P⁺ not
    /// positive definite, non-finite result) nothing is modified.
    pub fn joseph_update(
        &mut self,
        m: usize,
        h: &[f64],
        r: &[f64],
        std: &[f64],
        mask: ObsMask,
    ) -> Result<f64, FilterError> {
        let d = self.d;
        let (idx, p) = masked_rows(mask, m);
        if p == 0 {
            return Ok(0.0);
        }
        // Gather the p masked rows.
        let mut hs: ObsMat = [0.0; MAX_OBS * MAX_STATE]; // p × d
        let mut rs = [0.0; MAX_OBS];
        let mut var = [0.0; MAX_OBS];
        for (a, &i) in idx[..p].iter().enumerate() {
            for j in 0..d {
                hs[a + j * p] = h[i + j * m];
            }
            rs[a] = r[i];
            var[a] = std[i] * std[i];
        }
        // PHᵀ (d × p) and S = H PHᵀ + R (p × p).
        let mut pht: ObsMat = [0.0; MAX_OBS * MAX_STATE];
        gauss::mul_bt(&self.cov, d, d, &hs, p, &mut pht);
        let mut s = [0.0; MAX_OBS * MAX_OBS];
        gauss::mul(&hs, p, d, &pht, p, &mut s);
        for a in 0..p {
            s[a + a * p] += var[a];
        }
        let (kt, log_ev) = gain_and_evidence(&mut s, &pht, d, p, &rs)?;
        let new_mean = gain_step(&self.mean, &kt, &rs, d, p);
        // Joseph form: (I − KH) P (I − KH)ᵀ + K R Kᵀ.
        let mut ikh: Mat = [0.0; MAX_STATE * MAX_STATE];
        for c in 0..d {
            for rr in 0..d {
                let mut v = if rr == c { 1.0 } else { 0.0 };
                for a in 0..p {
                    v -= kt[a + rr * p] * hs[a + c * p];
                }
                ikh[rr + c * d] = v;
            }
        }
        let mut tmp: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul(&ikh, d, d, &self.cov, d, &mut tmp);
        let mut new_cov: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul_bt(&tmp, d, d, &ikh, d, &mut new_cov);
        for c in 0..d {
            for rr in 0..d {
                let mut v = 0.0;
                for a in 0..p {
                    v += kt[a + rr * p] * var[a] * kt[a + c * p];
                }
                new_cov[rr + c * d] += v;
            }
        }
        gauss::symmetrize(&mut new_cov, d);
        self.accept(
            &new_mean,
            &new_cov,
            "updated covariance is not positive semi-definite",
        )?;
        Ok(log_ev)
    }

    /// The belief as a [`Gaussian`] (allocates; not on the step path).
    pub fn belief(&self) -> Gaussian {
        let d = self.d;
        let mut g = Gaussian::zeros(d);
        g.mean_mut().copy_from_slice(&self.mean[..d]);
        g.cov_mut().copy_from_slice(&self.cov[..d * d]);
        g
    }
}

fn check_time(t: f64) -> Result<(), FilterError> {
    if t.is_finite() {
        Ok(())
    } else {
        Err(FilterError::NonFinite("time"))
    }
}

/// `BayesFilter::reset` of a filter whose `try_reset` gave `r`: a refused
/// prior is logged and the belief kept (the trait's `reset` cannot fail).
pub(crate) fn reset_or_keep(name: &str, r: Result<(), FilterError>) {
    if let Err(e) = r {
        tracing::warn!("{name}: reset rejected ({e}); belief kept");
    }
}

/// The checks opening every `predict` from `now` to `t` under `u`: the
/// span t − now, or `None` when there is nothing to do (t = now).
pub(crate) fn predict_span(
    now: f64,
    t: f64,
    u: &[f64],
    dims: Dims,
) -> Result<Option<f64>, FilterError> {
    check_predict(now, t, u, dims)?;
    let dur = t - now;
    Ok((dur != 0.0).then_some(dur))
}

/// The diagnostics of a Gaussian filter's update: ESS 1, never resampled.
pub(crate) fn gaussian_info(log_evidence: f64) -> UpdateInfo {
    UpdateInfo {
        log_evidence,
        ess: 1.0,
        resampled: false,
    }
}

/// The observation rows a mask selects among the first `m` (in order), and
/// how many there are.
pub(crate) fn masked_rows(mask: ObsMask, m: usize) -> ([usize; MAX_OBS], usize) {
    let mut idx = [0usize; MAX_OBS];
    let mut p = 0;
    for i in mask.iter().take_while(|&i| i < m) {
        idx[p] = i;
        p += 1;
    }
    (idx, p)
}

/// The measurement's σ per component, or the model's when it carries none.
pub(crate) fn measurement_std<M: SdeModel + ?Sized>(
    model: &M,
    meas: &Measurement,
    m: usize,
) -> [f64; MAX_OBS] {
    let mut std = [0.0; MAX_OBS];
    match meas.std {
        Some(s) => std[..m].copy_from_slice(&s[..m]),
        None => model.obs_std(&mut std[..m]),
    }
    std
}

/// Gain and evidence of the masked update: from the innovation covariance
/// `s` (p × p, R included; symmetrised here), the cross covariance `c`
/// (d × p) and the innovation `rs` (p), returns Kᵀ = S⁻¹ Cᵀ (p × d) and
/// log N(rs; 0, S). `Err` when S is not positive definite.
pub(crate) fn gain_and_evidence(
    s: &mut [f64; MAX_OBS * MAX_OBS],
    c: &ObsMat,
    d: usize,
    p: usize,
    rs: &[f64],
) -> Result<(ObsMat, f64), FilterError> {
    gauss::symmetrize(s, p);
    let mut ls = *s;
    if !linalg::cholesky(&mut ls, p) {
        return Err(FilterError::Numerical("innovation covariance not PD"));
    }
    let mut kt: ObsMat = [0.0; MAX_OBS * MAX_STATE];
    for a in 0..p {
        for j in 0..d {
            kt[a + j * p] = c[j + a * d];
        }
    }
    linalg::chol_solve(&ls, p, &mut kt, d);
    let mut z = [0.0; MAX_OBS];
    z[..p].copy_from_slice(&rs[..p]);
    linalg::chol_solve(&ls, p, &mut z, 1);
    let quad: f64 = (0..p).map(|a| rs[a] * z[a]).sum();
    let log_ev = -0.5 * quad - 0.5 * linalg::chol_log_det(&ls, p) - p as f64 * HALF_LOG_2PI;
    Ok((kt, log_ev))
}

/// m + K r for Kᵀ (p × d) and r (p).
pub(crate) fn gain_step(
    mean: &[f64],
    kt: &ObsMat,
    rs: &[f64],
    d: usize,
    p: usize,
) -> [f64; MAX_STATE] {
    let mut out = [0.0; MAX_STATE];
    for j in 0..d {
        let mut v = mean[j];
        for a in 0..p {
            v += kt[a + j * p] * rs[a];
        }
        out[j] = v;
    }
    out
}
