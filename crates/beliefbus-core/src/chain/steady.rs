//! The `steady` placement's covariance: the posterior covariance a filter
//! settles to when the model, linearised at one point, is observed at a
//! fixed period — data-free (it depends on the model, the sensor and the
//! period, not on the measurements).
//!
//! Linearise dx = f(x, u) dt + F(x) dw, y = g(x) + v at (x̄, ū):
//! J = ∂f/∂x, H = ∂g/∂x, R = diag σ², and discretise exactly over the
//! sensor period Δ (Van Loan, [`LinearSde::discretize`]): A = e^{JΔ},
//! Q = ∫₀^Δ e^{Js} F Fᵀ e^{Jᵀs} ds. The filter-form discrete algebraic
//! Riccati recursion
//!
//! ```text
//! P⁻ = A P Aᵀ + Q,    K = P⁻Hᵀ (H P⁻ Hᵀ + R)⁻¹,    P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ
//! ```
//!
//! is iterated from Q to its fixed point P∞, the Kalman filter's posterior
//! covariance at steady state (it converges when (A, H) is detectable and
//! (A, Q^{1/2}) stabilisable, e.g. a position sensor on a rigid body whose
//! noise enters through its velocities; `docs/degenerate-chains.md`).
//! For a linear model P∞ is exactly the covariance the Kalman filter
//! reaches; for a nonlinear one it is the EKF's at the linearisation
//! point, which is what a chain version drawn around N(x̂, P∞) needs: the
//! shape and the correlations (position–velocity–attitude) of the
//! posterior it will carry.

use nalgebra::DMatrix;

use super::ChainError;
use crate::belief::Gaussian;
use crate::model::linear::LinearSde;
use crate::model::SdeJacobians;
use crate::{MAX_NOISE, MAX_OBS, MAX_STATE};

/// Iterations of the Riccati recursion at most (it contracts
/// geometrically; a sensor period far below the filter's time constants
/// takes a few thousand).
pub const MAX_ITERATIONS: usize = 200_000;

/// N(x̄, P∞): the steady-state posterior of `model` linearised at (`x`, `u`)
/// and observed every `dt` (see the module doc). Errors: bad sizes or `dt`,
/// a linearisation with non-finite entries, or a recursion that does not
/// settle (an undetectable unstable mode).
pub fn steady_posterior<M: SdeJacobians + ?Sized>(
    model: &M,
    x: &[f64],
    u: &[f64],
    dt: f64,
) -> Result<Gaussian, ChainError> {
    let dims = model.dims();
    let (d, k, m) = (dims.state, dims.noise, dims.obs);
    if x.len() != d || u.len() != dims.control || d == 0 || d > MAX_STATE {
        return Err(ChainError::Config(
            "steady covariance: state or control of the wrong size",
        ));
    }
    if k > MAX_NOISE || m == 0 || m > MAX_OBS {
        return Err(ChainError::Config(
            "steady covariance: the model needs 1..=MAX_OBS observations",
        ));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(ChainError::Delta(dt));
    }
    let mut j = [0.0; MAX_STATE * MAX_STATE];
    model.drift_jacobian(x, u, &mut j[..d * d]);
    let mut f = [0.0; MAX_STATE * MAX_NOISE];
    model.diffusion(x, &mut f[..d * k]);
    let mut h = [0.0; MAX_OBS * MAX_STATE];
    model.obs_jacobian(x, &mut h[..m * d]);
    let mut std = [0.0; MAX_OBS];
    model.obs_std(&mut std[..m]);
    let finite = |v: &[f64]| v.iter().all(|a| a.is_finite());
    if !(finite(&j[..d * d]) && finite(&f[..d * k]) && finite(&h[..m * d]) && finite(&std[..m]))
        || std[..m].iter().any(|s| !(*s > 0.0))
    {
        return Err(ChainError::Config(
            "steady covariance: non-finite linearisation or non-positive sensor std",
        ));
    }
    let lin = LinearSde::new(
        "linearised",
        DMatrix::from_column_slice(d, d, &j[..d * d]),
        DMatrix::zeros(d, 0),
        DMatrix::from_column_slice(d, k, &f[..d * k]),
        DMatrix::from_column_slice(m, d, &h[..m * d]),
        std[..m].to_vec(),
        *model.bounds(),
    );
    let disc = lin.discretize(dt);
    let p = riccati(&disc.ad, &disc.qd, &lin.c, &std[..m])?;
    let mut g = Gaussian::zeros(d);
    g.mean_mut().copy_from_slice(x);
    for a in 0..d {
        for c in 0..d {
            g.set_cov(a, c, 0.5 * (p[(a, c)] + p[(c, a)]));
        }
    }
    Ok(g)
}

/// The fixed point of the filter-form Riccati recursion (module doc),
/// started from Q; converged when one step changes P by less than 1e-12
/// of its largest entry.
fn riccati(
    a: &DMatrix<f64>,
    q: &DMatrix<f64>,
    h: &DMatrix<f64>,
    std: &[f64],
) -> Result<DMatrix<f64>, ChainError> {
    let d = a.nrows();
    let r = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        std.len(),
        std.iter().map(|s| s * s),
    ));
    let eye = DMatrix::<f64>::identity(d, d);
    let mut p = q.clone();
    for _ in 0..MAX_ITERATIONS {
        let pm = a * &p * a.transpose() + q;
        let s = h * &pm * h.transpose() + &r;
        let s_inv = s.try_inverse().ok_or(ChainError::Config(
            "steady covariance: singular innovation covariance",
        ))?;
        let kg = &pm * h.transpose() * s_inv;
        let ikh = &eye - &kg * h;
        let next = &ikh * &pm * ikh.transpose() + &kg * &r * kg.transpose();
        let scale = next.amax();
        if !scale.is_finite() {
            break;
        }
        let change = (&next - &p).amax();
        p = next;
        if change <= 1e-12 * scale {
            return Ok(p);
        }
    }
    Err(ChainError::Config(
        "steady covariance: the Riccati recursion does not settle (an unobserved unstable mode?)",
    ))
}

#[cfg(test)]
#[path = "steady_tests.rs"]
mod tests;
