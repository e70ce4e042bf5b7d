//! The refined re-observation step of implicit SLAM (paper 003 §4.2: "F^j
//! with variables x_n and θ_n, the feature observed at time t_n"), as an SMC
//! sampler with a backward kernel (Del Moral, Doucet & Jasra 2006).
//!
//! Particle j holds its path and a sampled value θ_old of the feature it
//! re-observes. The feature is drawn again, jointly with the pose, from
//!
//! ```text
//! F^j(x, θ) = ½‖x − f^j‖²_{Σ₁⁻¹} + ½‖z − h(x, θ)‖²_{Σ₂⁻¹} + F_past(θ),
//! F_past(θ) = Σ_{i ∈ earlier sightings} ½‖z_i − h(X_i^j, θ)‖²_{Σ₂⁻¹}      (exact terms)
//! (μ, H = LLᵀ) = Newton minimiser and Hessian,  v = (x, θ) = μ + L⁻ᵀ ξ   (5-D linear map)
//! ```
//!
//! θ_old is left behind; the sampler on the extended space (path, θ_new,
//! θ_old) stays exact for any backward kernel L(θ_old | ·). We take the
//! implicit-sampling (Laplace) approximation of θ's conditional given the
//! path before this step: L = N(μ_p, H_p⁻¹), (μ_p, H_p = L_p L_pᵀ) the
//! minimiser and Hessian of F_past. Then
//!
//! ```text
//! log W^j += [½ξᵀξ − F(v) − log det L] + [F_past(θ_old) − ½‖L_pᵀ(θ_old − μ_p)‖² + log det L_p]
//!            − ½ log det Σ₁ − ½ log det Σ₂ − log 2π
//! ```
//!
//! The second bracket is minus the implicit-sampling log weight θ_old would
//! have had drawn from F_past. For a linear-Gaussian model both brackets are
//! constants and the sum is log p(z | earlier data, path): the proposal is
//! the optimal one and the weight the Rao–Blackwellised (Kalman-marginal)
//! weight, whatever ξ and θ_old (`tests`). For the nonlinear model nothing
//! is linearised in the target: the weights stay exact, the Laplace
//! approximations only shape the proposal and the backward kernel.

use crate::laser::Curvature;
use nalgebra::{SMatrix, SVector};

/// A Newton minimum: μ, F(μ), the lower Cholesky factor L of the Hessian at
/// μ (exact, or Gauss–Newton where the exact one is not positive definite),
/// log det L and the steps taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Minimum<const N: usize> {
    pub mu: SVector<f64, N>,
    pub phi: f64,
    pub l: SMatrix<f64, N, N>,
    pub log_det_l: f64,
    pub iters: usize,
}

/// An objective: `eval(v, curvature, g, h)` writes ∇F and ∇²F (overwriting
/// g and h) and returns F(v).
pub trait Objective<const N: usize> {
    fn eval(
        &self,
        v: &SVector<f64, N>,
        curv: Curvature,
        g: &mut SVector<f64, N>,
        h: &mut SMatrix<f64, N, N>,
    ) -> f64;

    /// F(v) alone.
    fn value(&self, v: &SVector<f64, N>) -> f64 {
        let (mut g, mut h) = (SVector::zeros(), SMatrix::zeros());
        self.eval(v, Curvature::GaussNewton, &mut g, &mut h)
    }
}

fn factor<const N: usize>(
    obj: &impl Objective<N>,
    v: &SVector<f64, N>,
    g: &mut SVector<f64, N>,
    h: &mut SMatrix<f64, N, N>,
) -> Option<(f64, SMatrix<f64, N, N>)> {
    let val = obj.eval(v, Curvature::Exact, g, h);
    if let Some(c) = h.cholesky() {
        return Some((val, c.l()));
    }
    let val = obj.eval(v, Curvature::GaussNewton, g, h);
    h.cholesky().map(|c| (val, c.l()))
}

/// Damped Newton from v0 (backtracking on F, Gauss–Newton curvature where
/// the exact Hessian is not positive definite); None on a non-finite
/// iterate or a Hessian that no curvature makes positive definite.
pub fn newton<const N: usize>(
    obj: &impl Objective<N>,
    v0: SVector<f64, N>,
    max_iter: usize,
    tol: f64,
) -> Option<Minimum<N>> {
    let mut v = v0;
    let (mut g, mut h) = (SVector::zeros(), SMatrix::zeros());
    let (mut gn, mut hn) = (SVector::zeros(), SMatrix::zeros());
    let (mut val, mut l) = factor(obj, &v, &mut g, &mut h)?;
    let mut iters = 0;
    while iters < max_iter {
        let y = l.solve_lower_triangular(&g)?;
        let dir = -l.tr_solve_lower_triangular(&y)?;
        let dec = -g.dot(&dir);
        if !dec.is_finite() {
            return None;
        }
        if dec < tol {
            break;
        }
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..30 {
            let vn = v + dir * t;
            let fv = obj.eval(&vn, Curvature::Exact, &mut gn, &mut hn);
            if fv <= val - 1e-4 * t * dec {
                v = vn;
                let (fv, ln) = factor(obj, &v, &mut g, &mut h)?;
                val = fv;
                l = ln;
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        iters += 1;
        if !accepted {
            break;
        }
    }
    if !val.is_finite() || !v.iter().all(|c| c.is_finite()) {
        return None;
    }
    let log_det_l = (0..N).map(|i| l[(i, i)].ln()).sum();
    Some(Minimum {
        mu: v,
        phi: val,
        l,
        log_det_l,
        iters,
    })
}

/// The linear map v = μ + L⁻ᵀ ξ and ½ξᵀξ − F(v) − log det L.
pub fn linear_map<const N: usize>(
    obj: &impl Objective<N>,
    m: &Minimum<N>,
    xi: &SVector<f64, N>,
) -> Option<(SVector<f64, N>, f64)> {
    let v = m.mu + m.l.tr_solve_lower_triangular(xi)?;
    let inc = 0.5 * xi.dot(xi) - obj.value(&v) - m.log_det_l;
    inc.is_finite().then_some((v, inc))
}

/// The backward-kernel term F_past(θ_old) − ½‖L_pᵀ(θ_old − μ_p)‖² +
/// log det L_p, with (μ_p, L_p) from Newton on F_past started at θ_old.
pub fn backward_term<const K: usize>(
    past: &impl Objective<K>,
    old: &SVector<f64, K>,
    max_iter: usize,
    tol: f64,
) -> Option<(f64, Minimum<K>)> {
    let m = newton(past, *old, max_iter, tol)?;
    backward_at(past, old, &m).map(|t| (t, m))
}

/// The backward-kernel term with (μ_p, L_p) already found (by Newton on
/// the same F_past from the same θ_old).
pub fn backward_at<const K: usize>(
    past: &impl Objective<K>,
    old: &SVector<f64, K>,
    m: &Minimum<K>,
) -> Option<f64> {
    let d = m.l.transpose() * (old - m.mu);
    let t = past.value(old) - 0.5 * d.dot(&d) + m.log_det_l;
    t.is_finite().then_some(t)
}

/// The θ-block (rows and columns `at..at + 2`) of H⁻¹ = L⁻ᵀ L⁻¹.
pub fn cov_block<const N: usize>(
    l: &SMatrix<f64, N, N>,
    at: usize,
) -> Option<nalgebra::Matrix2<f64>> {
    let li = l.try_inverse()?;
    let hinv = li.transpose() * li;
    Some(nalgebra::Matrix2::new(
        hinv[(at, at)],
        hinv[(at, at + 1)],
        hinv[(at + 1, at)],
        hinv[(at + 1, at + 1)],
    ))
}
