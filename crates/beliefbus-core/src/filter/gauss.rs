//! Shared numerics of the Gaussian filters (Kalman, EKF, UKF) and of the
//! particle filter's prior: small dense products on column-major stack
//! buffers (dimensions ≤ [`MAX_STATE`]/[`MAX_OBS`], so nothing allocates;
//! the Cholesky factorisation is [`crate::math::linalg`]'s), prior
//! validation, and RK4 on the moment equations. The belief state and the
//! masked measurement update built on them are in `gauss_state`.

use super::FilterError;
use crate::belief::Gaussian;
use crate::math::linalg::cholesky_psd;
use crate::{MAX_OBS, MAX_STATE};

/// A d × d scratch matrix.
pub(crate) type Mat = [f64; MAX_STATE * MAX_STATE];
/// An m × d (or d × m) scratch matrix.
pub(crate) type ObsMat = [f64; MAX_OBS * MAX_STATE];

pub(crate) const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;

/// out = A·B with A r×k and B k×c (column-major, tight strides).
pub(crate) fn mul(a: &[f64], r: usize, k: usize, b: &[f64], c: usize, out: &mut [f64]) {
    for j in 0..c {
        for i in 0..r {
            let mut s = 0.0;
            for l in 0..k {
                s += a[i + l * r] * b[l + j * k];
            }
            out[i + j * r] = s;
        }
    }
}

/// out = A·Bᵀ with A r×k and B c×k.
pub(crate) fn mul_bt(a: &[f64], r: usize, k: usize, b: &[f64], c: usize, out: &mut [f64]) {
    for j in 0..c {
        for i in 0..r {
            let mut s = 0.0;
            for l in 0..k {
                s += a[i + l * r] * b[j + l * c];
            }
            out[i + j * r] = s;
        }
    }
}

/// Replace the n × n matrix by ½(P + Pᵀ).
pub(crate) fn symmetrize(p: &mut [f64], n: usize) {
    for j in 0..n {
        for i in (j + 1)..n {
            let v = 0.5 * (p[i + j * n] + p[j + i * n]);
            p[i + j * n] = v;
            p[j + i * n] = v;
        }
    }
}

/// Largest |P − Pᵀ| relative to the largest |P|.
pub(crate) fn asymmetry(p: &[f64], n: usize) -> f64 {
    let mut scale: f64 = 0.0;
    let mut asym: f64 = 0.0;
    for j in 0..n {
        for i in 0..n {
            scale = scale.max(p[i + j * n].abs());
            asym = asym.max((p[i + j * n] - p[j + i * n]).abs());
        }
    }
    if scale > 0.0 {
        asym / scale
    } else {
        0.0
    }
}

/// Whether the symmetric n × n matrix is finite and positive
/// semi-definite (pivots down to −1e-9 of its scale count as zero).
pub(crate) fn is_psd(p: &[f64], n: usize) -> bool {
    let mut l: Mat = [0.0; MAX_STATE * MAX_STATE];
    l[..n * n].copy_from_slice(&p[..n * n]);
    p[..n * n].iter().all(|v| v.is_finite()) && cholesky_psd(&mut l, n)
}

/// Check a prior for a model of state dimension `d`: right dimension,
/// finite, symmetric and positive semi-definite.
pub fn check_prior(prior: &Gaussian, d: usize) -> Result<(), FilterError> {
    if prior.dim != d {
        return Err(FilterError::Dimension {
            what: "prior",
            got: prior.dim,
            expected: d,
        });
    }
    if !prior.is_finite() {
        return Err(FilterError::NonFinite("prior"));
    }
    if asymmetry(prior.cov(), d) > 1e-9 {
        return Err(FilterError::Numerical("prior covariance is not symmetric"));
    }
    let mut l: Mat = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(prior.cov());
    if cholesky_psd(&mut l, d) {
        Ok(())
    } else {
        Err(FilterError::Numerical(
            "prior covariance is not positive semi-definite",
        ))
    }
}

/// The lower factor L of a prior's covariance (L Lᵀ = P, semi-definite
/// allowed), for drawing samples m + L ξ.
pub(crate) fn prior_factor(prior: &Gaussian) -> Result<Mat, FilterError> {
    let d = prior.dim;
    let mut l: Mat = [0.0; MAX_STATE * MAX_STATE];
    l[..d * d].copy_from_slice(prior.cov());
    if !cholesky_psd(&mut l, d) {
        return Err(FilterError::Numerical(
            "prior covariance is not positive semi-definite",
        ));
    }
    Ok(l)
}

/// Classical RK4 on the moment equations ṁ = f(m), Ṗ = A P + P Aᵀ + F Fᵀ
/// (the EKF's continuous-time prediction): `steps` equal steps of `h`
/// from (`mean`, `cov`) (d and d × d column-major), with
/// `rhs(m, P, ṁ, Ṗ)` evaluating the right-hand side. No allocation.
pub fn rk4_moments(
    d: usize,
    mean: &mut [f64],
    cov: &mut [f64],
    h: f64,
    steps: usize,
    mut rhs: impl FnMut(&[f64], &[f64], &mut [f64], &mut [f64]),
) {
    let dd = d * d;
    // RK4 stages (k1..k4 for m and P) and the stage point.
    let mut km = [[0.0; MAX_STATE]; 4];
    let mut kp = [[0.0; MAX_STATE * MAX_STATE]; 4];
    let mut ms = [0.0; MAX_STATE];
    let mut ps = [0.0; MAX_STATE * MAX_STATE];
    for _ in 0..steps {
        for s in 0..4 {
            let c = match s {
                0 => 0.0,
                3 => h,
                _ => 0.5 * h,
            };
            if s == 0 {
                ms[..d].copy_from_slice(&mean[..d]);
                ps[..dd].copy_from_slice(&cov[..dd]);
            } else {
                for i in 0..d {
                    ms[i] = mean[i] + c * km[s - 1][i];
                }
                for i in 0..dd {
                    ps[i] = cov[i] + c * kp[s - 1][i];
                }
            }
            let (dm, dp) = (&mut km[s], &mut kp[s]);
            rhs(&ms[..d], &ps[..dd], &mut dm[..d], &mut dp[..dd]);
        }
        for i in 0..d {
            mean[i] += h / 6.0 * (km[0][i] + 2.0 * km[1][i] + 2.0 * km[2][i] + km[3][i]);
        }
        for i in 0..dd {
            cov[i] += h / 6.0 * (kp[0][i] + 2.0 * kp[1][i] + 2.0 * kp[2][i] + kp[3][i]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    #[test]
    fn products_match_nalgebra() {
        let a = DMatrix::from_fn(3, 4, |i, j| (i * 4 + j) as f64 * 0.3 - 1.0);
        let b = DMatrix::from_fn(4, 2, |i, j| (i + j) as f64 - 2.0);
        let c = DMatrix::from_fn(5, 4, |i, j| (i as f64 - j as f64) * 0.7);
        let mut out = [0.0; 64];
        mul(a.as_slice(), 3, 4, b.as_slice(), 2, &mut out);
        assert!(
            (DMatrix::from_column_slice(3, 2, &out[..6]) - &a * &b)
                .abs()
                .max()
                < 1e-12
        );
        mul_bt(a.as_slice(), 3, 4, c.as_slice(), 5, &mut out);
        let want = &a * c.transpose();
        assert!(
            (DMatrix::from_column_slice(3, 5, &out[..15]) - want)
                .abs()
                .max()
                < 1e-12
        );
    }
}
