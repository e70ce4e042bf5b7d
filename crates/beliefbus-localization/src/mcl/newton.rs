//! The per-particle objective of implicit MCL (paper 003 eq. 22 with the
//! ½ of erratum E9) and its minimisation by Newton's method with the
//! analytic gradient and Hessian:
//!
//! ```text
//! F^j(x) = ½ (x − f^j)ᵀ Σ₁⁻¹ (x − f^j) + Σ_i ½ ‖z^i − h(x, m^i)‖²_{Σ₂⁻¹}
//! ```
//!
//! Newton starts at the predicted mean f^j. Where the exact Hessian is not
//! positive definite (far from the minimum, or a large range residual) the
//! step uses the Gauss–Newton Hessian, which always is; a backtracking
//! (Armijo) line search keeps every step a descent. The returned Cholesky
//! factor is that of the exact Hessian at the end point, or of the
//! Gauss–Newton one if the exact one is not positive definite there: any
//! positive definite H keeps the linear-map weights exact, since the weight
//! e^{½ξᵀξ − F(X)}/det L is the ratio of the target to the proposal
//! N(μ, H⁻¹) whatever μ and H are.

use crate::error::LocalizationError;
use crate::geometry::{wrap_angle, Point, Pose};
use crate::laser::{add_term, term_cost, Curvature, LaserNoise, Observation};
use nalgebra::{Matrix3, Vector3};

/// F^j for one particle.
#[derive(Clone, Copy, Debug)]
pub struct Objective<'a> {
    /// The predicted mean f^j.
    pub f: Pose,
    /// Σ₁⁻¹ at the particle's heading.
    pub prec: Matrix3<f64>,
    pub obs: &'a [Observation],
    pub map: &'a [Point],
    pub laser: LaserNoise,
}

impl Objective<'_> {
    fn prior_diff(&self, x: &Pose) -> Vector3<f64> {
        let mut d = x - self.f;
        d[2] = wrap_angle(d[2]);
        d
    }

    /// F(x).
    pub fn value(&self, x: &Pose) -> f64 {
        let d = self.prior_diff(x);
        let mut v = 0.5 * d.dot(&(self.prec * d));
        for o in self.obs {
            v += term_cost(x, self.map[o.landmark], o, &self.laser);
        }
        v
    }

    /// F(x), writing ∇F into `g` and the Hessian (exact or Gauss–Newton) into `h`.
    pub fn eval(
        &self,
        x: &Pose,
        curv: Curvature,
        g: &mut Vector3<f64>,
        h: &mut Matrix3<f64>,
    ) -> f64 {
        let d = self.prior_diff(x);
        let pd = self.prec * d;
        *g = pd;
        *h = self.prec;
        let mut v = 0.5 * d.dot(&pd);
        for o in self.obs {
            v += add_term(x, self.map[o.landmark], o, &self.laser, curv, g, h);
        }
        v
    }
}

/// Newton's stopping rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NewtonSettings {
    /// At most this many Newton steps.
    pub max_iter: usize,
    /// Stop when the Newton decrement ∇Fᵀ H⁻¹ ∇F falls below this (F is
    /// then within about half of it of its minimum; the weights are exact
    /// for any end point, so this trades Newton steps for weight spread).
    pub tol: f64,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            max_iter: 20,
            tol: 1e-3,
        }
    }
}

/// The result of a minimisation.
#[derive(Clone, Copy, Debug)]
pub struct Minimum {
    pub mu: Pose,
    pub phi: f64,
    /// Lower Cholesky factor L of the Hessian at μ (H = LLᵀ).
    pub l: Matrix3<f64>,
    /// log det L.
    pub log_det_l: f64,
    pub iters: usize,
}

/// The Cholesky factor of `h` if positive definite.
fn chol(h: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    h.cholesky().map(|c| c.l())
}

/// A positive definite factor at x: the exact Hessian's, else Gauss–Newton's.
fn factor(
    obj: &Objective,
    x: &Pose,
    g: &mut Vector3<f64>,
    h: &mut Matrix3<f64>,
) -> Option<(f64, Matrix3<f64>)> {
    let v = obj.eval(x, Curvature::Exact, g, h);
    if let Some(l) = chol(h) {
        return Some((v, l));
    }
    let v = obj.eval(x, Curvature::GaussNewton, g, h);
    chol(h).map(|l| (v, l))
}

/// Minimise F from its predicted mean f.
pub fn minimise(
    obj: &Objective,
    s: &NewtonSettings,
    step: usize,
) -> Result<Minimum, LocalizationError> {
    let mut x = obj.f;
    let (mut g, mut h) = (Vector3::zeros(), Matrix3::zeros());
    let (mut gn, mut hn) = (Vector3::zeros(), Matrix3::zeros());
    let bad = || LocalizationError::NonFinite {
        what: "Newton iterate",
        step,
    };
    let (mut v, mut l) = factor(obj, &x, &mut g, &mut h).ok_or_else(bad)?;
    let mut iters = 0;
    while iters < s.max_iter {
        // Δ = −H⁻¹ g through the factor.
        let y = l.solve_lower_triangular(&g).ok_or_else(bad)?;
        let dir = -l.tr_solve_lower_triangular(&y).ok_or_else(bad)?;
        let decrement = -g.dot(&dir);
        if !decrement.is_finite() {
            return Err(bad());
        }
        if decrement < s.tol {
            break;
        }
        // Backtracking; a trial point's full evaluation is kept when it is
        // accepted, so an accepted step costs one evaluation.
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..30 {
            let xn = x + dir * t;
            let vn = obj.eval(&xn, Curvature::Exact, &mut gn, &mut hn);
            if vn <= v - 1e-4 * t * decrement {
                x = xn;
                v = vn;
                g = gn;
                l = match chol(&hn) {
                    Some(l) => l,
                    None => {
                        obj.eval(&x, Curvature::GaussNewton, &mut g, &mut h);
                        chol(&h).ok_or_else(bad)?
                    }
                };
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
    if !v.is_finite() || !x.iter().all(|c| c.is_finite()) {
        return Err(bad());
    }
    let log_det_l = l[(0, 0)].ln() + l[(1, 1)].ln() + l[(2, 2)].ln();
    Ok(Minimum {
        mu: x,
        phi: v,
        l,
        log_det_l,
        iters,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laser::predict;

    #[test]
    fn newton_finds_a_stationary_point_with_a_positive_definite_hessian() {
        let map = [[10.0, 3.0], [6.0, -4.0], [14.0, 0.5]];
        let truth = Pose::new(0.3, -0.2, 0.1);
        let obs: Vec<Observation> = map
            .iter()
            .enumerate()
            .map(|(i, &m)| {
                let (r, b) = predict(&truth, m);
                Observation {
                    range: r + 0.1,
                    bearing: b - 0.01,
                    landmark: i,
                }
            })
            .collect();
        let obj = Objective {
            f: Pose::new(-0.5, 0.4, -0.2),
            prec: Matrix3::from_diagonal(&Vector3::new(4.0, 4.0, 20.0)),
            obs: &obs,
            map: &map,
            laser: LaserNoise::default(),
        };
        let m = minimise(&obj, &NewtonSettings::default(), 0).unwrap();
        let (mut g, mut h) = (Vector3::zeros(), Matrix3::zeros());
        let v = obj.eval(&m.mu, Curvature::Exact, &mut g, &mut h);
        assert!(g.norm() < 1e-4 * h.norm().sqrt(), "gradient {g}");
        assert!((v - m.phi).abs() < 1e-12);
        assert!((m.l * m.l.transpose() - h).norm() < 1e-8 * h.norm());
        // Exact data and a prior centred on the truth: μ is the truth, φ = 0.
        let exact: Vec<Observation> = map
            .iter()
            .enumerate()
            .map(|(i, &mk)| {
                let (r, b) = predict(&truth, mk);
                Observation {
                    range: r,
                    bearing: b,
                    landmark: i,
                }
            })
            .collect();
        let obj0 = Objective {
            f: truth,
            obs: &exact,
            ..obj
        };
        let m0 = minimise(&obj0, &NewtonSettings::default(), 0).unwrap();
        assert!((m0.mu - truth).norm() < 1e-12 && m0.phi.abs() < 1e-20 && m0.iters == 0);
        // No point nearby is lower.
        for k in 0..3 {
            for s in [-1e-3, 1e-3] {
                let mut x = m.mu;
                x[k] += s;
                assert!(obj.value(&x) >= m.phi);
            }
        }
    }
}
