//! The locally linearised transition of one layer step: RK4 on the moment
//! equations ṁ = f(m), Ṗ = J P + P Jᵀ + F Fᵀ with J = ∂f/∂x at m by
//! central differences (exact for linear drift and constant F).

use crate::model::{fd_step, SdeModel};
use crate::{MAX_NOISE, MAX_STATE};

/// Locally linearised Gaussian transition of dx = f dt + F dw over `tau`
/// from x: mean and covariance (column-major) by RK4 on the moment ODEs.
pub fn propagate_gaussian<M: SdeModel + ?Sized>(
    model: &M,
    x: &[f64],
    tau: f64,
    substeps: usize,
    mean: &mut [f64],
    cov: &mut [f64],
) {
    let d = x.len();
    let k = model.dims().noise;
    let c = model.dims().control;
    let u = [0.0; crate::MAX_CONTROL];
    let rhs = |m: &[f64], p: &[f64], dm: &mut [f64], dp: &mut [f64]| {
        let mut big_f = [0.0; MAX_STATE * MAX_NOISE];
        model.drift(m, &u[..c], dm);
        // J by central differences
        let mut jac = [0.0; MAX_STATE * MAX_STATE];
        let mut xp = [0.0; MAX_STATE];
        let mut fp = [0.0; MAX_STATE];
        let mut fm = [0.0; MAX_STATE];
        for j in 0..d {
            xp[..d].copy_from_slice(m);
            let h = fd_step(m[j]);
            xp[j] = m[j] + h;
            model.drift(&xp[..d], &u[..c], &mut fp[..d]);
            xp[j] = m[j] - h;
            model.drift(&xp[..d], &u[..c], &mut fm[..d]);
            for i in 0..d {
                jac[i + j * d] = (fp[i] - fm[i]) / (2.0 * h);
            }
        }
        model.diffusion(m, &mut big_f[..d * k]);
        for i in 0..d {
            for j in 0..d {
                let mut s = 0.0;
                for l in 0..d {
                    s += jac[i + l * d] * p[l + j * d] + p[i + l * d] * jac[j + l * d];
                }
                for l in 0..k {
                    s += big_f[i + l * d] * big_f[j + l * d];
                }
                dp[i + j * d] = s;
            }
        }
    };
    mean[..d].copy_from_slice(x);
    cov[..d * d].fill(0.0);
    let h = tau / substeps.max(1) as f64;
    crate::filter::gauss::rk4_moments(d, mean, cov, h, substeps.max(1), rhs);
}
